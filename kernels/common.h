/* Shared definitions of the exabricks kernels: constants and small helpers.
 *
 * Coordinates: geometry (bricks, regions, BVH nodes) is in lattice units
 * (finest-cell units); rays are transformed into lattice space but keep their
 * parameter t in world distance, so step lengths and opacity correction are
 * in world units (docs/design-rendering.md, "Integration and images"). */
#pragma once

/* Every array bound (EB_STACK_SIZE, EB_MAX_SAMPLES, EB_MAX_ISO, ...) and the
 * frame's parameters (eb_params) come from the host's one declaration,
 * exabricks.device.kernel_abi, whose header() exabricks.device.opencl.program_for puts in
 * front of every program; the variant defines (EB_N_FIELDS, EB_SURFACES, ...)
 * come from kernel_abi.variant_defines. The host keeps its inputs within the
 * bounds: every tree is checked on load to be at most EB_STACK_SIZE levels deep
 * (a descent that pushes both children of a node and pops one never holds more
 * entries than the tree has levels), and a sampling rate that would need more
 * than EB_MAX_SAMPLES samples on a ray is refused, so no input makes a kernel
 * loop forever. */
#ifndef EB_ABI
#error "build through exabricks.device.opencl.program_for (it prepends exabricks.device.kernel_abi.header())"
#endif
#ifndef EB_N_FIELDS
#error "build with the defines of exabricks.device.kernel_abi.variant_defines (EB_N_FIELDS)"
#endif

#define EB_INF INFINITY

/* The frame's parameters (eb_params), as the kernels take them
 * (exabricks.device.kernel_abi.params_by_value): by value, which on NVIDIA
 * leaves them in the kernel's parameter bank, read where used (from a
 * __constant buffer the offsets into the dataset's buffers were loaded once
 * and held in registers across the ray loop: 16 of them); in a __constant
 * buffer in builds with out-of-line functions (-DEB_SURFACES: surfaces.cl's
 * EB_COLD), whose pointer to a by-value argument would copy it to the stack. */
#ifdef EB_SURFACES
typedef __constant eb_params *eb_params_ref;
#define EB_PARAMS_ARG __constant eb_params *P
#define EB_PARAMS_REF
#else
typedef const eb_params *eb_params_ref;
#define EB_PARAMS_ARG eb_params params
#define EB_PARAMS_REF eb_params_ref P = &params;
#endif

/* Level of detail (--lod): the frame's (eb_params.lod_scale > 0), or the build's
 * (-DEB_LOD=0 or 1: CPU programs, where the choice per sample made the one-sample
 * path 1.1-1.3 times slower on PoCL; exabricks.engine.variants). */
#ifdef EB_LOD
#define EB_LOD_ON(P) (EB_LOD)
#else
#define EB_LOD_ON(P) ((P)->lod_scale > 0.0f)
#endif

/* Volume samples' normals from central differences of the reconstructed field
 * (-DEB_CENTRAL: the "central" gradient, and the nearest reconstruction's),
 * else from the analytic gradient. A build option, not a frame parameter: the
 * six point queries of a central difference would hold registers in every
 * frame that never takes them. */
#ifdef EB_CENTRAL
#define EB_CENTRAL_NORMALS 1
#else
#define EB_CENTRAL_NORMALS 0
#endif

/* Force inlining of the hot helpers: PoCL's LLVM otherwise keeps some of them
 * (eb_add_brick, eb_queue_expand) as calls, so the sums go through memory and
 * a constant want_gradient is not folded away. */
#define EB_INLINE inline __attribute__((always_inline))

/* Rare, heavy paths kept out of line (an iso crossing's refinement, a surface
 * hit): inlined into every copy of the ray loop they made the kernel so large
 * that LLVM's compile time went superlinear (minutes per program variant with
 * surfaces on 2 cores; docs/design-kernels.md "Kernel builds and the host–kernel contract"). */
#define EB_COLD __attribute__((noinline))

/* The few functions that are kept out of line in a profiling build
 * (-DEB_PROFILE, benchmarks.profile_render), so that a sampling profiler
 * sees the walk and the sampling as separate symbols. */
#ifdef EB_PROFILE
#define EB_PROFILED __attribute__((noinline))
#else
#define EB_PROFILED EB_INLINE
#endif

/* Entry and exit distance of the ray org + t * dir through the box [lo, hi]
 * (inv_dir = 1 / dir, +-inf on axes the ray runs parallel to). The ray misses
 * where .x > .y. fmin/fmax drop the NaN that 0 * inf gives when the origin lies
 * exactly on a slab plane. */
EB_INLINE float2 eb_box_interval(float3 lo, float3 hi, float3 org, float3 inv_dir)
{
    float3 t0 = (lo - org) * inv_dir;
    float3 t1 = (hi - org) * inv_dir;
    float3 tn = fmin(t0, t1);
    float3 tf = fmax(t0, t1);
    return (float2)(fmax(fmax(tn.x, tn.y), tn.z), fmin(fmin(tf.x, tf.y), tf.z));
}

inline int eb_point_in_box(float3 p, float3 lo, float3 hi)
{
    return p.x >= lo.x && p.y >= lo.y && p.z >= lo.z &&
           p.x <= hi.x && p.y <= hi.y && p.z <= hi.z;
}
