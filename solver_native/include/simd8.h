// Eight float lanes as a GCC vector extension: one AVX register with -mavx (PUPPET_NATIVE_ARCH),
// two SSE registers otherwise. Operations are lane-wise; comparisons give lane masks.
#pragma once

// Everything here has internal linkage: each kernel translation unit (compiled for its own
// instruction set) gets its own copy, so the linker can never mix them.
namespace puppet::simd {
namespace {

typedef float f8 __attribute__((vector_size(32)));
typedef int i8 __attribute__((vector_size(32)));
typedef float f8u __attribute__((vector_size(32), aligned(4)));  // unaligned loads/stores

#define PUPPET_INLINE __attribute__((always_inline)) inline
#define PUPPET_INLINE_LAMBDA __attribute__((always_inline))

PUPPET_INLINE f8 splat(float x) { return f8{x, x, x, x, x, x, x, x}; }
PUPPET_INLINE f8 load(const float* p) { return *reinterpret_cast<const f8u*>(p); }
PUPPET_INLINE void store(float* p, f8 v) { *reinterpret_cast<f8u*>(p) = v; }

}  // namespace
}  // namespace puppet::simd
