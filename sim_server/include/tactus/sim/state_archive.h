#pragma once
// The simulation state in bytes (docs/design.md, "State: copy, save, restore"). One archive walks
// every member of the state in both directions: each object's transferState(StateArchive&)
// names its members once, and the same call writes them (saving) or reads them back
// (restoring), so a save and a restore cannot disagree on what the state is. Not installed.
//
// Each field is written as a 32-bit tag (FNV-1a of its name) and its value; a reader that meets
// another tag, a size that does not match the live object, or the end of the bytes stops with a
// StateError naming the field's path ("tissues[0].fem.q"). Values are native (little-endian
// x86-64) bytes: a state file is for the machine architecture that wrote it.
//
// What is a field: arithmetic and enum values, Eigen dense matrices and quaternions,
// shared::Pose, std::array and std::vector of those (a vector of plain values or fixed-size
// Eigen types is one block), unordered maps (written sorted by key, so equal states give equal
// bytes), and any type with a member transferState(StateArchive&). operator() requires sizes to
// match the live object (they come from the model); resizable() lets the reader resize.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "tactus/shared/error.h"
#include "tactus/shared/pose.h"

namespace tactus::sim {

class StateArchive {
 public:
  /// A writer appending to `out`.
  explicit StateArchive(std::string& out) : out_(&out) {}
  /// A reader of `in` (which must outlive it); `source` names the state in messages.
  StateArchive(std::string_view in, std::string source) : in_(in), source_(std::move(source)) {}

  bool loading() const { return out_ == nullptr; }

  /// Names the fields written inside it in messages (a path element such as "tissues[2]").
  class Scope {
   public:
    Scope(StateArchive& ar, std::string name) : ar_(ar), size_(ar.path_.size()) {
      if (!ar_.path_.empty()) ar_.path_ += '.';
      ar_.path_ += name;
    }
    ~Scope() { ar_.path_.resize(size_); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    StateArchive& ar_;
    std::size_t size_;
  };

  /// A field whose sizes come from the model: a reader refuses other sizes.
  template <class T>
  void operator()(std::string_view name, T& value) {
    tag(name);
    io(name, value, false);
  }

  /// A field whose size is state (a list that grows and shrinks): a reader resizes it, refusing
  /// sizes above `max_size` entries.
  template <class T>
  void resizable(std::string_view name, T& value, std::size_t max_size) {
    tag(name);
    max_size_ = max_size;
    io(name, value, true);
  }

  /// A field that is `n` values at `data` (a reader refuses another count).
  template <class S>
  void block(std::string_view name, S* data, std::size_t n) {
    static_assert(std::is_arithmetic_v<S>);
    tag(name);
    count(name, n, false, sizeof(S));
    bytes(data, n * sizeof(S));
  }

  /// Raw bytes (no tag, no count: the caller checks).
  void bytes(void* data, std::size_t n) {
    if (n == 0) return;
    if (!loading()) {
      out_->append(static_cast<const char*>(data), n);
      return;
    }
    if (n > in_.size() - at_) fail("", "the state ends inside it (truncated or not a state)");
    std::memcpy(data, in_.data() + at_, n);
    at_ += n;
  }

  /// Bytes not read yet.
  std::size_t remaining() const { return loading() ? in_.size() - at_ : 0; }

  /// Throws StateError "<source>: state field '<path>.<name>': <problem>".
  [[noreturn]] void fail(std::string_view name, std::string_view problem) const {
    std::string where = path_;
    if (!name.empty()) {
      if (!where.empty()) where += '.';
      where += name;
    }
    throw StateError(source_ + ": state field '" + where + "': " + std::string(problem));
  }

 private:
  static std::uint32_t tagOf(std::string_view name) {
    std::uint32_t h = 2166136261u;
    for (const char c : name) {
      h ^= static_cast<unsigned char>(c);
      h *= 16777619u;
    }
    return h;
  }

  void tag(std::string_view name) {
    std::uint32_t t = tagOf(name);
    if (!loading()) {
      bytes(&t, sizeof t);
      return;
    }
    std::uint32_t found = 0;
    if (remaining() < sizeof found) fail(name, "the state ends before it (truncated)");
    bytes(&found, sizeof found);
    if (found != t) {
      fail(name, "not found where expected (the state was written by another version of "
                 "Tactus, or is corrupt)");
    }
  }

  std::uint64_t count(std::string_view name, std::uint64_t live, bool resizable,
                      std::size_t entry_bytes) {
    std::uint64_t n = live;
    bytes(&n, sizeof n);
    if (!loading()) return n;
    if (resizable) {
      if (n > max_size_) {
        fail(name, "holds " + std::to_string(n) + " entries, more than the " +
                       std::to_string(max_size_) + " it may have");
      }
      if (entry_bytes > 0 && n > remaining() / entry_bytes) {
        fail(name, "holds more entries than the state has bytes (truncated or corrupt)");
      }
    } else if (n != live) {
      fail(name, "holds " + std::to_string(n) + " entries where this model has " +
                     std::to_string(live) + " (a state of another model)");
    }
    return n;
  }

  template <class T>
  static constexpr bool kPlain = std::is_arithmetic_v<T> || std::is_enum_v<T>;

  // A vector of these is written as one block of bytes (no padding inside them).
  template <class T>
  static constexpr bool isBlockEntry() {
    if constexpr (kPlain<T>) {
      return !std::is_same_v<T, bool>;
    } else if constexpr (requires { T::RowsAtCompileTime; T::ColsAtCompileTime; }) {
      return T::RowsAtCompileTime > 0 && T::ColsAtCompileTime > 0 &&
             std::is_arithmetic_v<typename T::Scalar>;
    } else {
      return false;
    }
  }

  template <class T>
  void io(std::string_view name, T& value, bool resizable) {
    if constexpr (kPlain<T>) {
      bytes(&value, sizeof value);
    } else if constexpr (requires { value.transferState(*this); }) {
      Scope s(*this, std::string(name));
      value.transferState(*this);
    } else if constexpr (std::is_same_v<T, shared::Pose>) {
      bytes(value.pos_m.data(), 3 * sizeof(double));
      bytes(value.rot.coeffs().data(), 4 * sizeof(double));
    } else if constexpr (std::is_same_v<T, Eigen::Quaterniond>) {
      bytes(value.coeffs().data(), 4 * sizeof(double));
    } else if constexpr (requires { T::RowsAtCompileTime; value.resize(0, 0); }) {
      eigen(name, value, resizable);
    } else if constexpr (requires { typename T::key_type; typename T::mapped_type; }) {
      map(name, value);
    } else if constexpr (requires { std::tuple_size<T>::value; value.data(); }) {
      for (auto& x : value) io(name, x, false);   // std::array
    } else if constexpr (requires { typename T::value_type; value.resize(0); }) {
      vector(name, value, resizable);
    } else {
      static_assert(sizeof(T) == 0, "StateArchive: no rule for this field's type");
    }
  }

  template <class M>
  void eigen(std::string_view name, M& m, bool resizable) {
    using Scalar = typename M::Scalar;
    std::int64_t rc[2] = {static_cast<std::int64_t>(m.rows()), static_cast<std::int64_t>(m.cols())};
    bytes(rc, sizeof rc);
    if (loading()) {
      if (rc[0] < 0 || rc[1] < 0) fail(name, "has a negative size (corrupt)");
      const bool same = rc[0] == m.rows() && rc[1] == m.cols();
      if (!same && !resizable) {
        fail(name, "is " + std::to_string(rc[0]) + " x " + std::to_string(rc[1]) +
                       " where this model has " + std::to_string(m.rows()) + " x " +
                       std::to_string(m.cols()) + " (a state of another model)");
      }
      const auto n = static_cast<std::uint64_t>(rc[0]) * static_cast<std::uint64_t>(rc[1]);
      if (n > max_size_ && !same) fail(name, "is larger than it may be");
      if (n > remaining() / sizeof(Scalar)) fail(name, "is larger than the state (truncated)");
      if (!same) m.resize(rc[0], rc[1]);
    }
    bytes(m.data(), static_cast<std::size_t>(m.size()) * sizeof(Scalar));
  }

  template <class V>
  void vector(std::string_view name, V& v, bool resizable) {
    using E = typename V::value_type;
    constexpr std::size_t entry = isBlockEntry<E>() ? sizeof(E) : 1;
    const std::uint64_t n = count(name, v.size(), resizable, entry);
    if (loading() && n != v.size()) {
      if constexpr (std::is_default_constructible_v<E>) {
        v.resize(static_cast<std::size_t>(n));
      } else {
        fail(name, "cannot change its number of entries");
      }
    }
    if constexpr (isBlockEntry<E>()) {
      bytes(v.data(), v.size() * sizeof(E));
    } else if constexpr (std::is_same_v<E, bool>) {
      for (std::size_t i = 0; i < v.size(); ++i) {
        std::uint8_t b = v[i] ? 1 : 0;
        bytes(&b, 1);
        v[i] = b != 0;
      }
    } else {
      for (std::size_t i = 0; i < v.size(); ++i) {
        io(std::string(name) + "[" + std::to_string(i) + "]", v[i], false);
      }
    }
  }

  template <class Map>
  void map(std::string_view name, Map& m) {
    using K = typename Map::key_type;
    using V = typename Map::mapped_type;
    static_assert(kPlain<K>, "StateArchive: map keys must be plain values");
    const std::uint64_t n = count(name, m.size(), true, sizeof(K));
    if (!loading()) {
      std::vector<std::pair<K, const V*>> sorted;
      sorted.reserve(m.size());
      for (const auto& [k, v] : m) sorted.emplace_back(k, &v);
      std::sort(sorted.begin(), sorted.end(),
                [](const auto& a, const auto& b) { return a.first < b.first; });
      for (auto& [k, v] : sorted) {
        K key = k;
        bytes(&key, sizeof key);
        io(name, const_cast<V&>(*v), false);
      }
      return;
    }
    m.clear();
    m.reserve(static_cast<std::size_t>(n));
    for (std::uint64_t i = 0; i < n; ++i) {
      K key{};
      bytes(&key, sizeof key);
      V value{};
      io(name, value, false);
      if (!m.emplace(key, std::move(value)).second) fail(name, "repeats a key (corrupt)");
    }
  }

  std::string* out_ = nullptr;
  std::string_view in_;
  std::size_t at_ = 0;
  std::string source_;
  std::string path_;
  std::size_t max_size_ = 0;
};

/// Members of an aggregate (its top-level fields), counted at compile time: the state walkers
/// compare it with the number of members they name, so a member added to a state struct and
/// forgotten by its transferState stops the build (docs/design.md, "State: copy, save, restore").
namespace state_detail {
struct AnyField {
  template <class T>
  operator T() const;   // declared only: used in unevaluated braced initialisers
};
template <class T, class... A>
constexpr int aggregateFieldCount() {
  if constexpr (requires { T{A{}..., AnyField{}}; }) {
    return aggregateFieldCount<T, A..., AnyField>();
  } else {
    return static_cast<int>(sizeof...(A));
  }
}
}  // namespace state_detail

template <class T>
inline constexpr int kAggregateFields = state_detail::aggregateFieldCount<T>();

}  // namespace tactus::sim
