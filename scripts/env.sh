# Sourced by the scripts: run-time environment for the daemons and tools.
# OpenBLAS 0.3.21 (Debian 12) does not recognise some virtual CPUs and falls back to slow SSE3
# kernels for CHOLMOD's supernodal factorisation; name the kernel family the CPU supports.
# A kernel family already named in the environment is kept only when this CPU can run it:
# OpenBLAS takes the name as given and dies with SIGILL at its first call otherwise.
tactus_cpu_flags=" $(grep -m1 '^flags' /proc/cpuinfo 2>/dev/null | cut -d: -f2) "
tactus_cpu_has() { [[ "$tactus_cpu_flags" == *" $1 "* ]]; }
if [[ -n "${OPENBLAS_CORETYPE:-}" ]]; then
  case "${OPENBLAS_CORETYPE,,}" in
    skylakex|cooperlake|sapphirerapids) tactus_core_needs=avx512f ;;
    haswell|zen) tactus_core_needs=avx2 ;;
    sandybridge) tactus_core_needs=avx ;;
    *) tactus_core_needs="" ;;
  esac
  if [[ -n "$tactus_core_needs" ]] && ! tactus_cpu_has "$tactus_core_needs"; then
    echo "tactus: ignoring OPENBLAS_CORETYPE=$OPENBLAS_CORETYPE: this CPU lacks $tactus_core_needs" \
         "(OpenBLAS would die with SIGILL); choosing one this CPU runs" >&2
    unset OPENBLAS_CORETYPE
  fi
  unset tactus_core_needs
fi
if [[ -z "${OPENBLAS_CORETYPE:-}" ]]; then
  if tactus_cpu_has avx512f; then export OPENBLAS_CORETYPE=SkylakeX
  elif tactus_cpu_has avx2; then export OPENBLAS_CORETYPE=Haswell
  fi
fi
unset tactus_cpu_flags
unset -f tactus_cpu_has
# One BLAS/OpenMP thread for the daemons and tools: the machine has two cores and the haptic loop
# owns one, so a multi-threaded OpenBLAS worker (it spins in sched_yield between calls) only
# steals from it. sim_server also sets this itself (openblas_set_num_threads(1)).
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
# glibc's malloc: blocks up to 32 MiB from the heap, and the heap's free top kept up to 1 GiB.
# The simulation's steps allocate and free the same large temporaries every step (CHOLMOD's
# solve buffers, W, the rows' right-hand sides: MBs at organ scale); by default each of those above
# glibc's mmap threshold was a fresh mmap, its pages faulted in and zeroed again every step, which
# cost a third of the CPU of the exact-compliance contact tests (docs/measurements.md, "Build and
# test time"). A setting already in the environment is kept.
export GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=1073741824}"
