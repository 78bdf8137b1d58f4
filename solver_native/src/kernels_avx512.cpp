// Kernels compiled with AVX-512 (F, VL, DQ, BW) on 8-lane (256-bit) vectors, see CMakeLists.txt;
// only called where the CPU has all of them. The vectors stay AVX2-wide: what AVX-512 adds here is
// 32 vector registers instead of 16 (the interleaved rotation fit's batches spill far less) and
// mask registers that merge a select into the operation before it.
#if defined(__x86_64__)
#define PUPPET_KERNEL_NS avx512
#include "kernels_impl.inc"
#endif
