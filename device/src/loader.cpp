#include <dlfcn.h>
#include <sys/stat.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <functional>

#include "tactus/device/backends.h"
#include "tactus/device/bridge_device.h"
#include "tactus/device/device.h"
#include "tactus/device/plugin_abi.h"
#include "tactus/shared/file_io.h"

namespace tactus::device {

namespace {

using Factory = std::function<std::unique_ptr<Device>(const DeviceConfig&)>;

// Built-in backends, in a static table (vendor backends behind CMake options would go here).
const std::map<std::string, Factory>& builtinTable() {
  static const std::map<std::string, Factory> table = {
      {"bridge", [](const DeviceConfig& c) { return std::make_unique<BridgeDevice>(c); }},
      {"null", [](const DeviceConfig& c) { return std::make_unique<NullDevice>(c); }},
      {"replay", [](const DeviceConfig& c) { return std::make_unique<ReplayDevice>(c); }},
      {"simulated", [](const DeviceConfig& c) { return std::make_unique<SimulatedDevice>(c); }},
  };
  return table;
}

std::string builtinList() {
  std::string s;
  for (const auto& [name, factory] : builtinTable()) s += (s.empty() ? "" : ", ") + name;
  return s;
}

bool fileExists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

// Owns a dlopen handle; closed after the device using it is destroyed.
struct Library {
  void* handle = nullptr;
  ~Library() {
    if (handle != nullptr) ::dlclose(handle);
  }
};

constexpr std::size_t kErrorBytes = 512;
/// Largest recorder ring (samples, and commands): 2^24, about 4.6 hours at 1 kHz between two
/// drains of the background writer, and 2 GB of memory at most.
constexpr double kMaxRecordCapacity = 16'777'216.0;

// The text a plugin wrote into an error buffer of `size` bytes: at most size - 1 bytes (the ABI
// promises a terminated message within the buffer; a plugin may still leave it unterminated, so
// nothing past the buffer is read), control bytes escaped.
std::string pluginMessage(const char* err, std::size_t size, const char* fallback) {
  const std::size_t n = size > 0 ? ::strnlen(err, size - 1) : 0;
  if (n == 0) return fallback;
  return shared::printable(std::string_view(err, n), size);
}

// A Device over the plugin C ABI. Every call into the plugin is wrapped: an exception escaping
// it (against the ABI's contract) is caught here, at the C boundary, so that it never reaches the
// real-time loop: read/write report kFault (the loop fades the force out), the other entries
// throw DeviceError.
class PluginDevice final : public Device {
 public:
  PluginDevice(std::shared_ptr<Library> lib, const TactusDevicePlugin* plugin,
               bool has_halt, std::string origin, const DeviceConfig& config)
      : lib_(std::move(lib)), plugin_(plugin), has_halt_(has_halt), origin_(std::move(origin)) {
    std::vector<TactusKeyValue> kv;
    kv.reserve(config.size());
    for (const auto& [k, v] : config) kv.push_back({k.c_str(), v.c_str()});
    char err[kErrorBytes] = {0};
    try {
      handle_ = plugin_->create(kv.empty() ? nullptr : kv.data(), kv.size(), err, sizeof(err));
    } catch (...) {
      throw DeviceError(prefix() + "create threw an exception (a plugin's entries must not): " +
                        what());
    }
    if (handle_ == nullptr) {
      throw DeviceError(prefix() + "create failed: " +
                        pluginMessage(err, sizeof(err), "no reason given"));
    }
  }
  ~PluginDevice() override {
    if (handle_ != nullptr) {
      close();
      try {
        plugin_->destroy(handle_);
      } catch (...) {
        // nothing sensible to do in a destructor: the plugin broke its contract
      }
    }
  }

  DeviceInfo info() const override {
    TactusDeviceInfo ci{};
    DeviceInfo i;
    int rc = TACTUS_DEVICE_ERROR;
    try {
      rc = plugin_->info(handle_, &ci);
    } catch (...) {
      throw DeviceError(prefix() + "info() threw an exception: " + what());
    }
    if (rc != TACTUS_DEVICE_OK) throw DeviceError(prefix() + "info() failed");
    ci.model[sizeof(ci.model) - 1] = '\0';
    i.model = shared::printable(ci.model, sizeof(ci.model));
    i.max_force_n = ci.max_force_n;
    i.has_rotation = ci.has_rotation != 0;
    i.has_gripper = ci.has_gripper != 0;
    return i;
  }
  void open() override {
    call("open", [&](char* err, std::size_t n) { return plugin_->open(handle_, err, n); });
    opened_ = true;
  }
  void calibrate() override {
    call("calibration", [&](char* err, std::size_t n) {
      return plugin_->calibrate(handle_, err, n);
    });
  }
  void enableForces(bool on) override {
    call(on ? "enabling forces" : "disabling forces", [&](char* err, std::size_t n) {
      return plugin_->enable_forces(handle_, on ? 1 : 0, err, n);
    });
  }
  void close() noexcept override {
    if (opened_) {
      try {
        plugin_->close(handle_);
      } catch (...) {
        // the plugin broke its contract; it is closed as far as we are concerned
      }
    }
    opened_ = false;
  }
  IoStatus read(DeviceState* out) noexcept override {
    TactusDeviceState s{};
    int rc = TACTUS_IO_FAULT;
    try {
      rc = plugin_->read(handle_, &s);
    } catch (...) {
      caught(read_exceptions_);
      return IoStatus::kFault;
    }
    if (rc != TACTUS_IO_OK) return rc == TACTUS_IO_NO_DATA ? IoStatus::kNoData : IoStatus::kFault;
    out->t_ns = s.t_ns;
    for (std::size_t i = 0; i < 3; ++i) {
      out->pos_m[i] = s.pos_m[i];
      out->vel_mps[i] = s.vel_mps[i];
      out->angvel_radps[i] = s.angvel_radps[i];
    }
    for (std::size_t i = 0; i < 4; ++i) out->quat_wxyz[i] = s.quat_wxyz[i];
    out->gripper_rad = s.gripper_rad;
    out->buttons = s.buttons;
    return IoStatus::kOk;
  }
  IoStatus write(const DeviceCommand& cmd) noexcept override {
    TactusDeviceCommand c{};
    for (std::size_t i = 0; i < 3; ++i) {
      c.force_n[i] = cmd.force_n[i];
      c.torque_nm[i] = cmd.torque_nm[i];
    }
    int rc = TACTUS_IO_FAULT;
    try {
      rc = plugin_->write(handle_, &c);
    } catch (...) {
      caught(write_exceptions_);
      return IoStatus::kFault;
    }
    if (rc == TACTUS_IO_OK) return IoStatus::kOk;
    return rc == TACTUS_IO_NO_DATA ? IoStatus::kNoData : IoStatus::kFault;
  }
  bool halt() noexcept override {
    if (!has_halt_ || plugin_->halt == nullptr) return false;
    try {
      plugin_->halt(handle_);
    } catch (...) {
      return false;
    }
    return true;
  }
  std::string takeDiagnostics() override {
    const std::uint64_t r = read_exceptions_.load(std::memory_order_relaxed);
    const std::uint64_t w = write_exceptions_.load(std::memory_order_relaxed);
    if (r == reported_read_ && w == reported_write_) return {};
    std::string text = prefix() + "exceptions escaped read() " + std::to_string(r - reported_read_) +
                       " and write() " + std::to_string(w - reported_write_) +
                       " time(s) (caught; each counted as a device fault)";
    // acquire: pairs with the release in caught(): the message is complete
    if (first_message_ready_.load(std::memory_order_acquire) && !first_message_logged_) {
      text += "; the first: " + shared::printable(first_message_.data(), first_message_.size());
      first_message_logged_ = true;
    }
    reported_read_ = r;
    reported_write_ = w;
    return text;
  }

 private:
  std::string prefix() const {
    return "device plugin '" +
           shared::printable(plugin_->name != nullptr ? plugin_->name : "?", 64) + "' (" +
           origin_ + "): ";
  }
  // The current exception's message (non-real-time).
  static std::string what() {
    try {
      throw;
    } catch (const std::exception& e) {
      return shared::printable(e.what(), 256);
    } catch (...) {
      return "not a std::exception";
    }
  }
  // Calls a non-real-time entry with an error buffer; throws DeviceError naming `what` on an
  // error code or an exception.
  template <class Entry>
  void call(const char* what_failed, Entry entry) {
    char err[kErrorBytes] = {0};
    int rc = TACTUS_DEVICE_ERROR;
    try {
      rc = entry(err, sizeof(err));
    } catch (...) {
      throw DeviceError(prefix() + what_failed + " threw an exception (a plugin's entries must "
                        "not): " + what());
    }
    if (rc != TACTUS_DEVICE_OK) {
      throw DeviceError(prefix() + what_failed + " failed: " +
                        pluginMessage(err, sizeof(err), "no reason given"));
    }
  }
  // Inside a catch block on the real-time thread: count, and keep the very first message (a
  // bounded copy into a fixed buffer, no allocation).
  void caught(std::atomic<std::uint64_t>& counter) noexcept {
    // relaxed: a statistic
    counter.fetch_add(1, std::memory_order_relaxed);
    if (first_message_taken_) return;
    first_message_taken_ = true;
    const char* text = "not a std::exception";
    try {
      throw;
    } catch (const std::exception& e) {
      text = e.what();
    } catch (...) {
    }
    std::strncpy(first_message_.data(), text, first_message_.size() - 1);
    // release: the copy is complete before the flag is seen
    first_message_ready_.store(true, std::memory_order_release);
  }

  std::shared_ptr<Library> lib_;     // declared first: released last
  const TactusDevicePlugin* plugin_;
  bool has_halt_ = false;            ///< an ABI 2 table (version 1 has no halt entry)
  std::string origin_;
  TactusDeviceHandle handle_ = nullptr;
  bool opened_ = false;
  // exceptions caught on the real-time thread (counted there, reported by takeDiagnostics)
  std::atomic<std::uint64_t> read_exceptions_{0};
  std::atomic<std::uint64_t> write_exceptions_{0};
  bool first_message_taken_ = false;                ///< real-time thread only
  std::array<char, 160> first_message_{};
  std::atomic<bool> first_message_ready_{false};
  bool first_message_logged_ = false;               ///< takeDiagnostics' thread only
  std::uint64_t reported_read_ = 0, reported_write_ = 0;
};

std::unique_ptr<Device> loadPlugin(const std::string& request, const DeviceConfig& config) {
  const bool is_path = request.find('/') != std::string::npos ||
                       (request.size() > 3 && request.compare(request.size() - 3, 3, ".so") == 0);
  std::vector<std::string> candidates;
  if (is_path) {
    candidates.push_back(request);
  } else {
    // $TACTUS_DEVICE_PATH folders, then the dynamic loader's own search
    if (const char* env = std::getenv("TACTUS_DEVICE_PATH"); env != nullptr) {
      std::string dirs(env);
      std::size_t pos = 0;
      while (pos <= dirs.size()) {
        const std::size_t colon = std::min(dirs.find(':', pos), dirs.size());
        const std::string dir = dirs.substr(pos, colon - pos);
        if (!dir.empty()) candidates.push_back(dir + "/lib" + request + ".so");
        pos = colon + 1;
      }
    }
    candidates.push_back("lib" + request + ".so");
  }

  auto lib = std::make_shared<Library>();
  std::string origin, why;
  for (const std::string& c : candidates) {
    if (c.find('/') != std::string::npos && !fileExists(c)) {
      why += "\n  " + c + ": no such file";
      continue;
    }
    ::dlerror();
    lib->handle = ::dlopen(c.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (lib->handle != nullptr) {
      origin = c;
      break;
    }
    const char* e = ::dlerror();
    why += "\n  " + c + ": " + (e != nullptr ? e : "dlopen failed");
  }
  if (lib->handle == nullptr) {
    if (is_path) {
      throw DeviceError("device backend '" + request + "': cannot load the plugin library:" + why +
                        "\nCheck the path (build the plugin first), or use a built-in backend: " +
                        builtinList() + ".");
    }
    throw DeviceError("device backend '" + request + "' is not built in (" + builtinList() +
                      ") and no plugin lib" + request + ".so was found:" + why +
                      "\nPass the path to the plugin's .so, or put its folder on "
                      "TACTUS_DEVICE_PATH.");
  }

  ::dlerror();
  void* sym = ::dlsym(lib->handle, TACTUS_DEVICE_PLUGIN_SYMBOL);
  if (sym == nullptr) {
    throw DeviceError("device plugin '" + origin + "' does not export '" +
                      std::string(TACTUS_DEVICE_PLUGIN_SYMBOL) +
                      "': define extern \"C\" const TactusDevicePlugin* tactus_device_plugin(void) "
                      "as in device/include/tactus/device/plugin_abi.h (see device/README.md, "
                      "\"Write your own device backend\") and rebuild it");
  }
  TactusDevicePluginEntry entry = nullptr;
  static_assert(sizeof(entry) == sizeof(sym));
  std::memcpy(&entry, &sym, sizeof(sym));
  const TactusDevicePlugin* plugin = entry();
  if (plugin == nullptr) {
    throw DeviceError("device plugin '" + origin + "': tactus_device_plugin() returned NULL");
  }
  // version 2, or version 1 (the same table without halt): both load
  const bool v1 = plugin->abi_version == 1u;
  if (plugin->abi_version != TACTUS_DEVICE_PLUGIN_ABI_VERSION && !v1) {
    throw DeviceError("device plugin '" + origin + "' was built for device plugin ABI version " +
                      std::to_string(plugin->abi_version) + ", this program loads versions 1 to " +
                      std::to_string(TACTUS_DEVICE_PLUGIN_ABI_VERSION) +
                      ": rebuild the plugin against this checkout's "
                      "device/include/tactus/device/plugin_abi.h");
  }
  const std::size_t expected_size = v1 ? TACTUS_DEVICE_PLUGIN_V1_SIZE : sizeof(TactusDevicePlugin);
  if (plugin->struct_size != expected_size) {
    throw DeviceError("device plugin '" + origin + "' has a function table of " +
                      std::to_string(plugin->struct_size) + " bytes for ABI version " +
                      std::to_string(plugin->abi_version) + ", expected " +
                      std::to_string(expected_size) +
                      ": rebuild the plugin against this checkout's plugin_abi.h");
  }
  const bool complete = plugin->create && plugin->destroy && plugin->open && plugin->calibrate &&
                        plugin->enable_forces && plugin->close && plugin->read && plugin->write &&
                        plugin->info;
  if (!complete) {
    throw DeviceError("device plugin '" + origin + "' leaves some functions of its "
                      "TactusDevicePlugin table NULL: every entry must be set");
  }
  return std::make_unique<PluginDevice>(std::move(lib), plugin, /*has_halt=*/!v1, origin, config);
}

}  // namespace

std::vector<std::string> builtinDeviceNames() {
  std::vector<std::string> names;
  for (const auto& [name, factory] : builtinTable()) names.push_back(name);
  return names;
}

std::unique_ptr<Device> loadDevice(std::string_view name_or_path, const DeviceConfig& config) {
  const std::string request = name_or_path.empty() ? std::string(kDefaultDevice)
                                                   : std::string(name_or_path);
  // the recorder wraps any backend; its options are not the backend's
  DeviceConfig inner_config = config;
  std::string record;
  std::size_t record_capacity = std::size_t{1} << 16;
  if (auto it = inner_config.find("record"); it != inner_config.end()) {
    record = it->second;
    inner_config.erase(it);
    if (record.empty()) throw DeviceError("device option record= needs a file name");
  }
  std::string record_commands;
  if (auto it = inner_config.find("record_commands"); it != inner_config.end()) {
    record_commands = it->second;
    inner_config.erase(it);
    if (record_commands.empty()) {
      throw DeviceError("device option record_commands= needs a file name");
    }
  }
  bool record_overwrite = false;
  if (auto it = inner_config.find("record_overwrite"); it != inner_config.end()) {
    OptionReader opt("recorder", inner_config);
    record_overwrite = opt.flag("record_overwrite", false);
    inner_config.erase("record_overwrite");
  }
  if (auto it = inner_config.find("record_capacity"); it != inner_config.end()) {
    OptionReader opt("recorder", inner_config);
    // the rings are allocated at once (a sample or command each): bounded, as memory is
    const double cap = opt.number("record_capacity", 0.0, 2.0, kMaxRecordCapacity);
    if (cap != std::floor(cap)) {
      throw DeviceError("device option record_capacity must be a whole number of samples");
    }
    record_capacity = static_cast<std::size_t>(cap);
    inner_config.erase("record_capacity");
  }

  std::unique_ptr<Device> device;
  const auto& table = builtinTable();
  if (auto it = table.find(request); it != table.end()) {
    device = it->second(inner_config);
  } else {
    device = loadPlugin(request, inner_config);
  }
  if (!record.empty() || !record_commands.empty()) {
    device = std::make_unique<RecordingDevice>(std::move(device), record, record_capacity,
                                               record_overwrite, record_commands);
  }
  return device;
}

}  // namespace tactus::device
