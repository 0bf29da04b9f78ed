/* Shared definitions of the exabricks kernels: constants and small helpers.
 *
 * Coordinates: geometry (bricks, regions, BVH nodes) is in lattice units
 * (finest-cell units); rays are transformed into lattice space but keep their
 * parameter t in world distance, so step lengths and opacity correction are
 * in world units (docs/design.md, "Integration and images"). */
#pragma once

/* Depth of the private BVH traversal stack: a BVH over 2**31 regions built by
 * any sane builder is far shallower (each stack entry is one deferred sibling). */
#define EB_STACK_SIZE 64

#define EB_INF INFINITY

/* Force inlining of the hot helpers: PoCL's LLVM otherwise keeps some of them
 * (eb_add_brick, eb_queue_expand) as calls, so the sums go through memory and
 * a constant want_gradient is not folded away. */
#define EB_INLINE inline __attribute__((always_inline))

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
