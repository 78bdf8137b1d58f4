// Kernels compiled with AVX-512 (F, VL, DQ, BW) on 8-lane (256-bit) vectors, see CMakeLists.txt;
// only called where the CPU has all of them. The vectors stay AVX2-wide, except the interleaved
// rotation fit's, which runs batches of sixteen lanes (one 512-bit register each) while 48 matrices
// remain: the fit is latency-bound and a 512-bit operation has about the latency of a 256-bit one.
// What AVX-512 adds besides: 32 vector registers instead of 16 (the interleaved fit's batches spill
// far less, and the covariance gather runs 64-row tiles) and mask registers that merge a select
// into the operation before it.
#if defined(__x86_64__)
#define PUPPET_KERNEL_NS avx512
#include "kernels_impl.inc"
#endif
