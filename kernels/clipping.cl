/* Clipping (docs/design-rendering.md, "Surfaces, slices and clipping"): what is
 * kept is the inside of an optional box and, for each plane (P, N), the
 * half-space (p - P) . N >= 0, all in world units. Their intersection is
 * convex, so a ray keeps one interval [t0, t1] of it: the integrator walks only
 * that interval, which cuts volumes, iso-surfaces and slices exactly. */
#pragma once
#include "common.h"

typedef struct {
    int has_box;
    float4 box_lower, box_upper;   /* world units */
    __global const float4 *planes; /* point, normal, point, normal, ... (world) */
    int n_planes;
} eb_clip;

/* The kept interval of the ray org + t dir (world units, t >= t_min); empty
 * when .x >= .y. */
EB_INLINE float2 eb_clip_interval(eb_clip clip, float3 org, float3 dir, float t_min)
{
    float t0 = t_min, t1 = EB_INF;
    if (clip.has_box) {
        float2 iv = eb_box_interval(clip.box_lower.xyz, clip.box_upper.xyz, org, 1.0f / dir);
        t0 = fmax(t0, iv.x);
        t1 = fmin(t1, iv.y);
    }
    for (int k = 0; k < clip.n_planes; ++k) {
        float3 point = clip.planes[2 * k].xyz, normal = clip.planes[2 * k + 1].xyz;
        /* (org + t dir - P) . N >= 0  <=>  t (dir . N) >= (P - org) . N */
        float along = dot(dir, normal), need = dot(point - org, normal);
        if (along > 0.0f)
            t0 = fmax(t0, need / along);
        else if (along < 0.0f)
            t1 = fmin(t1, need / along);
        else if (need > 0.0f)
            t1 = -EB_INF;  /* parallel to the plane, on the removed side */
    }
    return (float2)(t0, t1);
}
