#include "fclib_hdf5.h"

#include <hdf5.h>

#include <algorithm>
#include <string>
#include <type_traits>
#include <vector>

#include "tactus/shared/error.h"

namespace tactus::shared {
namespace {

// Owns an HDF5 file handle.
class H5File {
 public:
  explicit H5File(const std::filesystem::path& path) : name_(path.string()) {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // our messages, not HDF5's stack dump
    id_ = H5Fopen(name_.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    if (id_ < 0) throw Error(name_ + ": cannot open as HDF5 (missing file or not HDF5)");
  }
  ~H5File() { H5Fclose(id_); }
  H5File(const H5File&) = delete;
  H5File& operator=(const H5File&) = delete;

  // Reads a whole dataset converted to T (native int or double).
  template <class T>
  std::vector<T> read(const std::string& dataset) const {
    if (H5Lexists(id_, dataset.c_str(), H5P_DEFAULT) <= 0) {
      throw Error(name_ + ": dataset " + dataset + " is missing (not an FCLIB local problem?)");
    }
    const hid_t ds = H5Dopen2(id_, dataset.c_str(), H5P_DEFAULT);
    if (ds < 0) throw Error(name_ + ": cannot open dataset " + dataset);
    const hid_t space = H5Dget_space(ds);
    const hssize_t n = H5Sget_simple_extent_npoints(space);
    std::vector<T> out(n > 0 ? static_cast<std::size_t>(n) : 0);
    const hid_t type = std::is_same_v<T, double> ? H5T_NATIVE_DOUBLE : H5T_NATIVE_INT;
    const herr_t st =
        out.empty() ? 0 : H5Dread(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data());
    H5Sclose(space);
    H5Dclose(ds);
    if (n < 0 || st < 0) throw Error(name_ + ": cannot read dataset " + dataset);
    return out;
  }

  int scalar(const std::string& dataset) const {
    const auto v = read<int>(dataset);
    if (v.size() != 1) throw Error(name_ + ": dataset " + dataset + " is not a scalar");
    return v[0];
  }

 private:
  std::string name_;
  hid_t id_ = -1;
};

}  // namespace

FclibProblem readFclibHdf5(const std::filesystem::path& path) {
  const std::string file = path.string();
  const H5File h5(path);
  const int spacedim = h5.scalar("/fclib_local/spacedim");
  if (spacedim != 3) {
    throw Error(file + ": /fclib_local/spacedim is " + std::to_string(spacedim) +
                ", only 3D problems are supported");
  }
  const int m = h5.scalar("/fclib_local/W/m");
  const int n = h5.scalar("/fclib_local/W/n");
  const int nz = h5.scalar("/fclib_local/W/nz");
  if (m != n || m < 3 || m % 3 != 0) {
    throw Error(file + ": W is " + std::to_string(m) + " x " + std::to_string(n) +
                ", expected square with 3 rows per contact");
  }
  const auto p = h5.read<int>("/fclib_local/W/p");
  const auto i = h5.read<int>("/fclib_local/W/i");
  const auto x = h5.read<double>("/fclib_local/W/x");
  auto q = h5.read<double>("/fclib_local/vectors/q");
  auto mu = h5.read<double>("/fclib_local/vectors/mu");

  // expand W to triplets (row, col, value)
  std::vector<int> rows, cols;
  std::vector<double> vals;
  auto compressed = [&](int outer, bool csc) {
    if (static_cast<int>(p.size()) < outer + 1) {
      throw Error(file + ": /fclib_local/W/p has " + std::to_string(p.size()) +
                  " entries, expected " + std::to_string(outer + 1));
    }
    for (int o = 0; o < outer; ++o) {
      const int stored = static_cast<int>(std::min(i.size(), x.size()));
      if (p[o] < 0 || p[o] > p[o + 1] || p[o + 1] > stored) {
        throw Error(file + ": /fclib_local/W/p is not a valid pointer array at " +
                    std::to_string(o));
      }
      for (int k = p[o]; k < p[o + 1]; ++k) {
        rows.push_back(csc ? i[k] : o);
        cols.push_back(csc ? o : i[k]);
        vals.push_back(x[k]);
      }
    }
  };
  if (nz == -1) {
    compressed(n, true);
  } else if (nz == -2) {
    compressed(m, false);
  } else if (nz >= 0) {
    if (p.size() < static_cast<std::size_t>(nz) || i.size() < static_cast<std::size_t>(nz) ||
        x.size() < static_cast<std::size_t>(nz)) {
      throw Error(file + ": W triplet arrays hold fewer than nz = " + std::to_string(nz) +
                  " entries");
    }
    rows.assign(i.begin(), i.begin() + nz);
    cols.assign(p.begin(), p.begin() + nz);
    vals.assign(x.begin(), x.begin() + nz);
  } else {
    throw Error(file + ": /fclib_local/W/nz = " + std::to_string(nz) + " is not a known storage");
  }
  std::string name = path.filename().string();
  if (name.size() > 5 && name.ends_with(".hdf5")) name.resize(name.size() - 5);
  return assembleFclibProblem(file, name, std::move(mu), std::move(q), rows, cols, vals);
}

}  // namespace tactus::shared
