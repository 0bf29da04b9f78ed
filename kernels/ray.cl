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

/* The samples per level of a --lod frame (`lod`: EB_LOD_ON; nothing otherwise),
 * added to the frame's counts (level_samples, one per level) region by region:
 * no state a ray holds through its loop (per-ray counts spilled the GPU default). */
EB_INLINE void eb_level_samples_add(__global uint *level_samples, int lod, int level, uint n)
{
    if (lod && n)
        atomic_add(&level_samples[min(level, EB_LOD_LEVELS - 1)], n);
}
