#pragma once
// FCLIB HDF5 input (/fclib_local/W/{m,n,nz,nzmax,p,i,x}, /fclib_local/vectors/{q,mu},
// /fclib_local/spacedim). Compiled only into tactus-fc3d-solve, and only when CMake finds HDF5
// (TACTUS_HAVE_HDF5), so the haptic process never links HDF5.

#include <filesystem>

#include "tactus/shared/fclib.h"

namespace tactus::shared {

/// Reads an FCLIB local problem. W may be CSC (nz = -1), CSR (nz = -2) or triplets (nz >= 0,
/// i = row, p = column). Throws tactus::Error naming the file and the dataset when the file
/// cannot be opened, a dataset is missing or inconsistent, or spacedim is not 3.
FclibProblem readFclibHdf5(const std::filesystem::path& path);

}  // namespace tactus::shared
