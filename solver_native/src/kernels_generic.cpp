// Kernels for the build's baseline instruction set (SSE2 on x86-64 unless PUPPET_NATIVE_ARCH).
#define PUPPET_KERNEL_NS generic
#include "kernels_impl.inc"
