/* Kernel entry points: `eb_render` (one frame sample per pixel) and `eb_probe`
 * (field values at points). Everything else lives in one file per concept. */
#include "common.h"
#include "sampler.cl"
#include "camera.cl"
#include "integrator.cl"
#include "dataset.cl"
#ifdef EB_MIXTURE
#include "mixture.cl"
#endif
#ifdef EB_PATH
#include "path.cl"
#endif

/* eb_render's domain argument (a domain of a frame split by space, P->domain:
 * frame.cl eb_in_domain): where use_front, the premultiplied RGBA of this sample
 * composited so far in front of the domain (one per pixel of the band), which
 * the domain's rays continue from (so that early ray termination carries
 * across domains; exabricks.engine.streaming). */
#define EB_DOMAIN_ARGS , __global const float4 *front

/* Sample `sample_index` of P->spp of every pixel in rows row0 .. row0 + rows - 1
 * and columns col0 .. col0 + cols - 1 (band = (row0, rows, col0, cols)) of the
 * P->width x P->height frame, with the parameters P (exabricks.device.kernel_abi.PARAMS;
 * EB_PARAMS_ARG, common.h) and the dataset's buffers (dataset.cl) (the host
 * renders a frame, or a tile of it, in bands of rows, so that each enqueue
 * ends well within a second and a signal can stop the run), averaged into
 * rgba, which holds that band, cols pixels a row (sample 0 overwrites, so the
 * buffer needs no clearing).
 * Sub-pixel position: the pixel centre for spp == 1, else uniform from the
 * seeded hash. Interleaving offset rho: from the hash with jitter, else 0.5.
 * counts holds per pixel of the band the reconstruction count over its samples,
 * then per pixel the smallest depth. */
__kernel void eb_render(EB_PARAMS_ARG, int4 band, int sample_index,
                        EB_DATASET_ARGS, __global const float *look_f, __global const int *look_i,
                        __global const float4 *meshes EB_LIGHT_ARGS EB_DOMAIN_ARGS, __global float4 *rgba,
                        __global uint *counts, __global uint *level_samples)
{
    EB_PARAMS_REF
    __global uint *samples = counts;  /* then, after the band's pixels, their depths */
    __global float *depth = (__global float *)(counts + band.y * band.w);
    int band_col = get_global_id(0), band_row = get_global_id(1);
    int col = band.z + band_col, row = band.x + band_row;
    int width = P->width, spp = P->spp;
    uint seed = P->seed;
    if (band_col >= band.w || band_row >= band.y || col >= width || row >= P->height)
        return;
    /* seeds the hash: bands and tiles change nothing */
    uint pixel = (uint)row * (uint)width + (uint)col;
    uint slot = (uint)band_row * (uint)band.w + (uint)band_col;
#include "frame_of.inc"

    float jx = 0.5f, jy = 0.5f;
    if (spp > 1) {
        float2 j = eb_r2(pixel, (uint)sample_index, seed, 1u);
        jx = j.x;
        jy = j.y;
    }
    eb_ray ray;
    ray.rho = P->jitter ? eb_offset(col, row, (uint)sample_index, seed) : 0.5f;
    ray.pixel = pixel;
    ray.sample = (uint)sample_index;
    ray.seed = seed;
    ray.org_world = P->cam_origin.xyz;
    ray.dir_world = eb_camera_direction(P->cam_forward.xyz, P->cam_du.xyz, P->cam_dv.xyz,
                                        col, row, width, P->height, jx, jy);
    ray.org = eb_world_to_lattice(P->cam_origin.xyz, P->origin_world.xyz, P->inv_spacing.xyz);
    ray.dir = ray.dir_world * P->inv_spacing.xyz;
    ray.inv_dir = 1.0f / ray.dir;
    uint n;
    float t_depth;
    float4 c;
    float4 before = (float4)(0.0f);
    if (P->use_front)
        before = front[slot];
    /* A constant shade argument lets the compiler drop the unused path. */
#if defined(EB_PATH)
    c = eb_path(&fr, &ray, look_f, &n, &t_depth, level_samples);
    (void)before;
#elif defined(EB_MIXTURE)
    c = P->shading ? eb_integrate_mixture(&fr, &ray, 1, &n, &t_depth, level_samples)
                   : eb_integrate_mixture(&fr, &ray, 0, &n, &t_depth, level_samples);
    (void)before;
#else
    c = P->shading ? eb_integrate(&fr, &ray, 1, before, &n, &t_depth, level_samples)
                   : eb_integrate(&fr, &ray, 0, before, &n, &t_depth, level_samples);
#endif
    c /= (float)spp;
    if (sample_index == 0) {
        rgba[slot] = c;
        samples[slot] = n;
        depth[slot] = t_depth;
    } else {
        rgba[slot] += c;
        samples[slot] += n;
        depth[slot] = fmin(depth[slot], t_depth);
    }
}

#ifdef EB_SHADOW
/* The shadow integrator's cached transmittance (light_volume.cl): columns (i, j0
 * + j) of the light-space volume, i < light_dims.x, j < rows, into light_volume. */
__kernel void eb_light_columns(EB_PARAMS_ARG, int j0, int rows, EB_DATASET_ARGS,
                               __global const float *look_f, __global const int *look_i,
                               __global const float4 *meshes, __global float *light_volume)
{
    EB_PARAMS_REF
    int i = get_global_id(0), j = j0 + get_global_id(1);
    if (i >= P->light_dims.x || get_global_id(1) >= rows || j >= P->light_dims.y)
        return;
#include "frame_of.inc"
    eb_light_column(&fr, i, j, light_volume + ((size_t)j * P->light_dims.x + i) * P->light_dims.z);
}
#endif

/* The reconstructed fields at n world points (x, y, z packed, float): field f
 * of point i in values[f * n + i]; NaN where no region contains the point or
 * no cell has support there (no containing cell, for nearest and vertex). */
__kernel void eb_probe(int n, __global const float *points_world, EB_PARAMS_ARG,
                       EB_DATASET_ARGS, __global float *values)
{
    EB_PARAMS_REF
    int i = get_global_id(0);
    if (i >= n)
        return;
    eb_bvh bvh = eb_bvh_of(P, EB_DATASET);
    eb_regions regions = eb_regions_of(P, EB_DATASET);
    eb_bricks bricks = eb_bricks_of(P, EB_DATASET);
    float3 p = eb_world_to_lattice(vload3(i, points_world), P->origin_world.xyz,
                                   P->inv_spacing.xyz);
    int r = eb_find_region(bvh, regions, p);
    eb_basis_sums s = eb_basis_zero();
    if (r >= 0)
        s = eb_reconstruct(bricks, regions.brick_ids, regions.brick_start[r],
                           regions.brick_start[r + 1], p, 0);
    for (int f = 0; f < EB_N_FIELDS; ++f)
        values[f * n + i] = s.weight > 0.0f ? eb_basis_value(s, f) : NAN;
}
