// The command-line interface of tactus/shared/cli.h, the only source that includes CLI11.
#include "tactus/shared/cli.h"

#include <CLI/CLI.hpp>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <utility>

namespace tactus::shared::cli {
namespace {

// A CLI11 validator as a project one: its check and its help text, unchanged.
Validator fromCli11(const CLI::Validator& validator) {
  return Validator([validator](std::string& text) { return validator(text); },
                   validator.get_description());
}

// Shortest readable text of a bound (1e+06, 0.05, 4000), for messages.
std::string boundText(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

// Finite and within the interval from lo to hi; `open_low` excludes lo itself.
Validator finiteInterval(double lo, double hi, const std::string& unit, bool open_low) {
  const std::string interval = (open_low ? "(" : "[") + boundText(lo) + ", " + boundText(hi) +
                               "]" + (unit.empty() ? "" : " " + unit);
  return Validator(
      [lo, hi, open_low, interval](std::string& text) -> std::string {
        double value = 0.0;
        if (!parseFiniteDouble(text, value)) return "must be a finite number (got '" + text + "')";
        const bool below = open_low ? !(value > lo) : value < lo;
        if (below || value > hi) return "must be in " + interval + " (got " + text + ")";
        return {};
      },
      "FINITE in " + interval);
}

}  // namespace

Validator::Validator(Check check, std::string description)
    : check_(std::move(check)), description_(std::move(description)) {}

Validator range(int lo, int hi) { return fromCli11(CLI::Range(lo, hi)); }
Validator range(long lo, long hi) { return fromCli11(CLI::Range(lo, hi)); }
Validator range(double lo, double hi) { return fromCli11(CLI::Range(lo, hi)); }
Validator isMember(std::vector<std::string> names) {
  return fromCli11(CLI::IsMember(std::move(names)));
}
Validator existingFile() { return fromCli11(CLI::ExistingFile); }
Validator positiveNumber() { return fromCli11(CLI::PositiveNumber); }

bool parseFiniteDouble(const std::string& text, double& value) {
  if (text.empty()) return false;
  errno = 0;
  char* end = nullptr;
  value = std::strtod(text.c_str(), &end);
  return errno == 0 && end == text.c_str() + text.size() && std::isfinite(value);
}

Validator finiteRange(double lo, double hi, const std::string& unit) {
  return finiteInterval(lo, hi, unit, false);
}

Validator finiteAbove(double lo, double hi, const std::string& unit) {
  return finiteInterval(lo, hi, unit, true);
}

Option* Option::check(const Validator& validator) {
  option_->check(CLI::Validator(validator.check(), validator.description()));
  return this;
}

Option* Option::captureDefault() {
  option_->capture_default_str();
  return this;
}

Option* Option::required() {
  option_->required();
  return this;
}

Option* Option::expected(int count) {
  option_->expected(count);
  return this;
}

Option* Option::delimiter(char separator) {
  option_->delimiter(separator);
  return this;
}

Option* Option::excludes(const std::string& other) {
  option_->excludes(other);
  return this;
}

Option* Option::needs(const std::string& other) {
  option_->needs(other);
  return this;
}

Option* Option::group(const std::string& name) {
  option_->group(name);
  return this;
}

App::App(std::string description) : app_(std::make_unique<CLI::App>(std::move(description))) {}

App::~App() = default;

void App::footer(std::string text) { app_->footer(std::move(text)); }

Option* App::keep(CLI::Option* option) { return &options_.emplace_back(option); }

// Each overload instantiates CLI11's add_option for its type, here and nowhere else.
#define TACTUS_CLI_ADD_OPTION(Type)                                                   \
  Option* App::addOption(std::string name, Type& value, std::string description) {    \
    return keep(app_->add_option(std::move(name), value, std::move(description)));    \
  }
TACTUS_CLI_ADD_OPTION(std::string)
TACTUS_CLI_ADD_OPTION(std::filesystem::path)
TACTUS_CLI_ADD_OPTION(double)
TACTUS_CLI_ADD_OPTION(int)
TACTUS_CLI_ADD_OPTION(long)
TACTUS_CLI_ADD_OPTION(long long)
TACTUS_CLI_ADD_OPTION(unsigned)
TACTUS_CLI_ADD_OPTION(unsigned long)
TACTUS_CLI_ADD_OPTION(unsigned long long)
TACTUS_CLI_ADD_OPTION(std::optional<std::string>)
TACTUS_CLI_ADD_OPTION(std::optional<double>)
TACTUS_CLI_ADD_OPTION(std::optional<int>)
TACTUS_CLI_ADD_OPTION(std::vector<std::string>)
TACTUS_CLI_ADD_OPTION(std::vector<std::filesystem::path>)
TACTUS_CLI_ADD_OPTION(std::vector<double>)
TACTUS_CLI_ADD_OPTION(std::vector<int>)
#undef TACTUS_CLI_ADD_OPTION

Option* App::addFlag(std::string name, bool& value, std::string description) {
  return keep(app_->add_flag(std::move(name), value, std::move(description)));
}

Option* App::addFlagCallback(std::string name, std::function<void()> callback,
                             std::string description) {
  return keep(app_->add_flag_callback(std::move(name), std::move(callback),
                                      std::move(description)));
}

std::optional<int> App::parse(int argc, const char* const* argv) {
  try {
    app_->parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app_->exit(e);
  }
  return std::nullopt;
}

}  // namespace tactus::shared::cli
