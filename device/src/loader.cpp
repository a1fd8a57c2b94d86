#include <dlfcn.h>
#include <sys/stat.h>

#include <cstdlib>
#include <cstring>
#include <functional>

#include "tactus/device/backends.h"
#include "tactus/device/bridge_device.h"
#include "tactus/device/device.h"
#include "tactus/device/plugin_abi.h"

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

// A Device over the plugin C ABI.
class PluginDevice final : public Device {
 public:
  PluginDevice(std::shared_ptr<Library> lib, const TactusDevicePlugin* plugin, std::string origin,
               const DeviceConfig& config)
      : lib_(std::move(lib)), plugin_(plugin), origin_(std::move(origin)) {
    std::vector<TactusKeyValue> kv;
    kv.reserve(config.size());
    for (const auto& [k, v] : config) kv.push_back({k.c_str(), v.c_str()});
    char err[kErrorBytes] = {0};
    handle_ = plugin_->create(kv.empty() ? nullptr : kv.data(), kv.size(), err, sizeof(err));
    if (handle_ == nullptr) {
      throw DeviceError(prefix() + "create failed: " + message(err, "no reason given"));
    }
  }
  ~PluginDevice() override {
    if (handle_ != nullptr) {
      close();
      plugin_->destroy(handle_);
    }
  }

  DeviceInfo info() const override {
    TactusDeviceInfo ci{};
    DeviceInfo i;
    if (plugin_->info(handle_, &ci) != TACTUS_DEVICE_OK) {
      throw DeviceError(prefix() + "info() failed");
    }
    ci.model[sizeof(ci.model) - 1] = '\0';
    i.model = ci.model;
    i.max_force_n = ci.max_force_n;
    i.max_stiffness_npm = ci.max_stiffness_npm;
    i.workspace_radius_m = ci.workspace_radius_m;
    i.has_rotation = ci.has_rotation != 0;
    i.has_gripper = ci.has_gripper != 0;
    return i;
  }
  void open() override {
    char err[kErrorBytes] = {0};
    if (plugin_->open(handle_, err, sizeof(err)) != TACTUS_DEVICE_OK) {
      throw DeviceError(prefix() + "open failed: " + message(err, "no reason given"));
    }
    opened_ = true;
  }
  void calibrate() override {
    char err[kErrorBytes] = {0};
    if (plugin_->calibrate(handle_, err, sizeof(err)) != TACTUS_DEVICE_OK) {
      throw DeviceError(prefix() + "calibration failed: " + message(err, "no reason given"));
    }
  }
  void enableForces(bool on) override {
    char err[kErrorBytes] = {0};
    if (plugin_->enable_forces(handle_, on ? 1 : 0, err, sizeof(err)) != TACTUS_DEVICE_OK) {
      throw DeviceError(prefix() + (on ? "enabling" : "disabling") + " forces failed: " +
                        message(err, "no reason given"));
    }
  }
  void close() noexcept override {
    if (opened_) plugin_->close(handle_);
    opened_ = false;
  }
  IoStatus read(DeviceState* out) noexcept override {
    TactusDeviceState s{};
    const int rc = plugin_->read(handle_, &s);
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
    c.gripper_force_n = cmd.gripper_force_n;
    const int rc = plugin_->write(handle_, &c);
    if (rc == TACTUS_IO_OK) return IoStatus::kOk;
    return rc == TACTUS_IO_NO_DATA ? IoStatus::kNoData : IoStatus::kFault;
  }

 private:
  std::string prefix() const {
    return "device plugin '" + std::string(plugin_->name != nullptr ? plugin_->name : "?") +
           "' (" + origin_ + "): ";
  }
  static std::string message(const char* err, const char* fallback) {
    return err[0] != '\0' ? std::string(err) : std::string(fallback);
  }

  std::shared_ptr<Library> lib_;     // declared first: released last
  const TactusDevicePlugin* plugin_;
  std::string origin_;
  TactusDeviceHandle handle_ = nullptr;
  bool opened_ = false;
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
  if (plugin->abi_version != TACTUS_DEVICE_PLUGIN_ABI_VERSION) {
    throw DeviceError("device plugin '" + origin + "' was built for device plugin ABI version " +
                      std::to_string(plugin->abi_version) + ", this program uses version " +
                      std::to_string(TACTUS_DEVICE_PLUGIN_ABI_VERSION) +
                      ": rebuild the plugin against this checkout's "
                      "device/include/tactus/device/plugin_abi.h");
  }
  if (plugin->struct_size != sizeof(TactusDevicePlugin)) {
    throw DeviceError("device plugin '" + origin + "' has a function table of " +
                      std::to_string(plugin->struct_size) + " bytes, expected " +
                      std::to_string(sizeof(TactusDevicePlugin)) +
                      ": rebuild the plugin against this checkout's plugin_abi.h");
  }
  const bool complete = plugin->create && plugin->destroy && plugin->open && plugin->calibrate &&
                        plugin->enable_forces && plugin->close && plugin->read && plugin->write &&
                        plugin->info;
  if (!complete) {
    throw DeviceError("device plugin '" + origin + "' leaves some functions of its "
                      "TactusDevicePlugin table NULL: every entry must be set");
  }
  return std::make_unique<PluginDevice>(std::move(lib), plugin, origin, config);
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
  bool record_overwrite = false;
  if (auto it = inner_config.find("record_overwrite"); it != inner_config.end()) {
    OptionReader opt("recorder", inner_config);
    record_overwrite = opt.flag("record_overwrite", false);
    inner_config.erase("record_overwrite");
  }
  if (auto it = inner_config.find("record_capacity"); it != inner_config.end()) {
    OptionReader opt("recorder", inner_config);
    const double cap = opt.number("record_capacity", 0.0);
    if (cap < 2.0) throw DeviceError("device option record_capacity must be >= 2 samples");
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
  if (!record.empty()) {
    device = std::make_unique<RecordingDevice>(std::move(device), record, record_capacity,
                                               record_overwrite);
  }
  return device;
}

}  // namespace tactus::device
