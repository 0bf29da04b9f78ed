/* One ray and what it has accumulated so far (the integrator's state). EB_N_FIELDS,
 * EB_MAX_SLICES and EB_LOD_LEVELS: exabricks.device.kernel_abi. */
#pragma once
#include "common.h"

/* One ray: in lattice space with t in world distance (dir_world unit length),
 * and what seeds its random numbers. */
typedef struct {
    float3 org, dir, inv_dir;      /* lattice space */
    float3 org_world, dir_world;
    float rho;                     /* interleaved-sampling offset */
    uint pixel, sample, seed;
} eb_ray;

/* What a ray has accumulated so far. */
typedef struct {
    float3 color;
    float transmittance;
    float t_depth;                 /* where the accumulated opacity first reached EB_DEPTH_OPACITY */
    float t_opaque;                /* the first opaque surface hit */
    uint samples;
#ifdef EB_LOD
    uint level_samples[EB_LOD_LEVELS];  /* reconstructions per level used */
#endif
    /* iso crossings: the previous sample (field values at prev_t) */
    int prev_valid;
    float prev_t;
    float prev[EB_N_FIELDS];
    float last_exit;               /* where the last region ended (a gap resets prev) */
    /* slices and mesh hits along the ray inside its clip interval, by distance
     * (slice_k: a slice's index, or -1 - a mesh triangle's) */
    float slice_t[EB_MAX_SLICES + EB_MAX_MESH_HITS];
    int slice_k[EB_MAX_SLICES + EB_MAX_MESH_HITS];
    int n_slices, next_slice;
} eb_ray_state;

/* The samples per level of a --lod frame (-DEB_LOD; nothing otherwise):
 * cleared, counted per region, and added to the frame's counts at the end. */
EB_INLINE void eb_level_samples_clear(eb_ray_state *st)
{
#ifdef EB_LOD
    for (int l = 0; l < EB_LOD_LEVELS; ++l)
        st->level_samples[l] = 0u;
#endif
}

EB_INLINE void eb_level_samples_add(eb_ray_state *st, int level, uint n)
{
#ifdef EB_LOD
    st->level_samples[min(level, EB_LOD_LEVELS - 1)] += n;
#endif
}

EB_INLINE void eb_level_samples_flush(eb_ray_state *st, __global uint *level_samples)
{
#ifdef EB_LOD
    for (int l = 0; l < EB_LOD_LEVELS; ++l)
        if (st->level_samples[l])
            atomic_add(&level_samples[l], st->level_samples[l]);
#endif
}
