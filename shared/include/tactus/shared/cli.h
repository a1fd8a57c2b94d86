// The daemons' and tools' command lines: a small interface over CLI11, compiled once.
//
// CLI11 2.1 is header-only: a program that included it compiled CLI11's parser, help formatter and
// validators again, about 7 s of CPU even with CLI11's own code at -O0, in each of the eleven
// programs (docs/measurements.md, "Build and test time"). This header declares only what the
// programs use; CLI11 is included by one source, shared/cli/cli.cpp, compiled once into the
// static library tactus::cli that the programs link. The help text, the error messages and the
// exit codes are CLI11's own: every call forwards to it.
//
// Usage (the names mirror CLI11's, in the project's camelBack):
//   namespace cli = tactus::shared::cli;
//   cli::App app{"What the program does"};
//   app.footer("Example:\n  program --rate 1000");
//   app.addOption("--rate", rate_hz, "Loop rate [Hz]")->check(cli::range(50.0, 4000.0))
//       ->captureDefault();
//   TACTUS_CLI_PARSE(app, argc, argv);   // returns from main on --help or a bad command line
//
// addOption binds a variable of one of the types listed below (an unlisted type does not compile:
// add an overload here and its definition in cli.cpp).
#pragma once

#include <cstdint>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace CLI {
class App;
class Option;
}  // namespace CLI

namespace tactus::shared::cli {

/// A check of an option's text: the function returns an empty string when the text is accepted,
/// else the reason (CLI11 adds the option's name); it may rewrite the text before it is converted.
/// The description is shown in the help after the option's type.
class Validator {
 public:
  using Check = std::function<std::string(std::string&)>;

  /// A check made by the program (for example a name's syntax), described as `description`.
  Validator(Check check, std::string description);

  /// The check itself.
  const Check& check() const { return check_; }
  /// The text the help shows for it.
  const std::string& description() const { return description_; }

 private:
  Check check_;
  std::string description_;
};

/// CLI11's Range: the value converted to the bound's type lies in [lo, hi] (compared with < and >,
/// so "nan" passes: for a value that reaches a device, a timer or a loop bound use finiteRange()).
Validator range(int lo, int hi);
Validator range(long lo, long hi);
Validator range(double lo, double hi);
/// CLI11's IsMember: the text is one of `names`.
Validator isMember(std::vector<std::string> names);
/// CLI11's ExistingFile: the text names an existing file (not a directory).
Validator existingFile();
/// CLI11's PositiveNumber: the text is a number greater than zero.
Validator positiveNumber();

/// Finite and within [lo, hi]. `unit` names the unit in the help text (for example "N").
/// Unlike range(), the text must parse completely as a finite number ("nan", "inf", "5x" fail).
Validator finiteRange(double lo, double hi, const std::string& unit = "");
/// Finite, strictly greater than lo and at most hi.
Validator finiteAbove(double lo, double hi, const std::string& unit = "");
/// Parses `text` as a finite double; false when it is empty, has trailing characters, overflows
/// or is NaN/Inf.
bool parseFiniteDouble(const std::string& text, double& value);

/// One option or flag of an App. Each call returns the option, so that calls chain with ->.
class Option {
 public:
  /// Adds a check of the option's text (several checks apply in turn).
  Option* check(const Validator& validator);
  /// Shows the bound variable's value at definition time as the default in the help.
  Option* captureDefault();
  /// The command line must give this option.
  Option* required();
  /// Number of values the option takes (for a vector-valued option).
  Option* expected(int count);
  /// Splits one value at `separator` into several (for a vector-valued option).
  Option* delimiter(char separator);
  /// The command line may not give both this option and `other` (named as on the command line).
  Option* excludes(const std::string& other);
  /// This option needs `other` (named as on the command line) to be given too.
  Option* needs(const std::string& other);
  /// Help section the option is listed under; an empty name hides it from the help.
  Option* group(const std::string& name);

  /// Wraps CLI11's option (made by App only).
  explicit Option(CLI::Option* option) : option_(option) {}

 private:
  CLI::Option* option_;
};

/// A program's command line: its options, its help and its parse.
class App {
 public:
  /// `description` heads the help.
  explicit App(std::string description);
  ~App();
  App(const App&) = delete;
  App& operator=(const App&) = delete;

  /// Text printed at the end of the help (the project's programs end it with an example).
  void footer(std::string text);

  /// An option with a value, bound to `value` (a name starting with "-" or "--"; a name without
  /// dashes is positional). The variable keeps its value when the option is not given.
  Option* addOption(std::string name, std::string& value, std::string description = "");
  Option* addOption(std::string name, std::filesystem::path& value, std::string description = "");
  Option* addOption(std::string name, double& value, std::string description = "");
  Option* addOption(std::string name, int& value, std::string description = "");
  Option* addOption(std::string name, long& value, std::string description = "");
  Option* addOption(std::string name, long long& value, std::string description = "");
  Option* addOption(std::string name, unsigned& value, std::string description = "");
  Option* addOption(std::string name, unsigned long& value, std::string description = "");
  Option* addOption(std::string name, unsigned long long& value, std::string description = "");
  Option* addOption(std::string name, std::optional<std::string>& value,
                    std::string description = "");
  Option* addOption(std::string name, std::optional<double>& value,
                    std::string description = "");
  Option* addOption(std::string name, std::optional<int>& value, std::string description = "");
  Option* addOption(std::string name, std::vector<std::string>& value,
                    std::string description = "");
  Option* addOption(std::string name, std::vector<std::filesystem::path>& value,
                    std::string description = "");
  Option* addOption(std::string name, std::vector<double>& value, std::string description = "");
  Option* addOption(std::string name, std::vector<int>& value, std::string description = "");

  /// A flag: `value` becomes true when the flag is given.
  Option* addFlag(std::string name, bool& value, std::string description = "");
  /// A flag that calls `callback` when given.
  Option* addFlagCallback(std::string name, std::function<void()> callback,
                          std::string description = "");

  /// Parses the command line. Empty when the program goes on; otherwise the help was printed
  /// (--help) or the error was reported on stderr, and the value is the exit status.
  std::optional<int> parse(int argc, const char* const* argv);

 private:
  Option* keep(CLI::Option* option);

  std::unique_ptr<CLI::App> app_;
  std::deque<Option> options_;  // a deque: the Option* handed out stay valid
};

}  // namespace tactus::shared::cli

/// Parses the command line in main(): returns from it with the exit status on --help or on an
/// error (as CLI11_PARSE does), and goes on otherwise.
#define TACTUS_CLI_PARSE(app, argc, argv)                                                 \
  do {                                                                                    \
    if (const std::optional<int> tactus_cli_exit = (app).parse((argc), (argv))) {        \
      return *tactus_cli_exit;                                                            \
    }                                                                                     \
  } while (false)
