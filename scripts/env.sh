# Sourced by the scripts: run-time environment for the daemons and tools.
# OpenBLAS 0.3.21 (Debian 12) does not recognise some virtual CPUs and falls back to slow SSE3
# kernels for CHOLMOD's supernodal factorisation; name the kernel family the CPU supports.
if [[ -z "${OPENBLAS_CORETYPE:-}" && -r /proc/cpuinfo ]]; then
  if grep -q -m1 avx512f /proc/cpuinfo; then export OPENBLAS_CORETYPE=SkylakeX
  elif grep -q -m1 avx2 /proc/cpuinfo; then export OPENBLAS_CORETYPE=Haswell
  fi
fi
# One BLAS/OpenMP thread for the daemons and tools: the machine has two cores and the haptic loop
# owns one, so a multi-threaded OpenBLAS worker (it spins in sched_yield between calls) only
# steals from it. sim_server also sets this itself (openblas_set_num_threads(1)).
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
