/* The uniform-grid ceiling of benchmarks/bench_peers.py: a minimal trilinear ray
 * marcher over one float volume (the dataset resampled at its finest
 * resolution), with the renderer's camera, transfer function, sample placement,
 * opacity correction, compositing and early termination, and none of its
 * traversal (no BVH, no regions, no space skipping, one constant step).
 *
 * Volume: voxel (i, j, k) is the finest cell whose lower corner is
 * lattice_lower + (i, j, k), value at its centre, x fastest. Between voxel
 * centres the value is trilinear, and up to one voxel outside the outermost
 * centres (half a cell beyond the data) it is clamped to the edge voxel: on a
 * single-level dataset that is exactly the basis reconstruction (paper eq. 1-2),
 * whose support is each cell grown by half its width, and where the one
 * remaining hat normalises to the edge value. NaN voxels (holes) make their
 * samples transparent.
 *
 * Samples (as kernels/integrator.cl does in a region of level 0): delimiters
 * t_k = (k + rho) dt split the ray's interval through the volume box, each
 * sub-interval is sampled once at its midpoint and weighted by its length.
 * Every trilinear lookup counts as one sample, as every reconstruction does in
 * eb_render.
 *
 * Like render.cl this is a program's main file (built on its own by
 * benchmarks/uniform_grid.py), so it has no #pragma once; what it includes
 * does. The sub-intervals (sampler.cl), the transfer function and opacity
 * correction (transfer_function.cl) and the compositing (compositing.cl) are
 * the renderer's own functions. */
#include "common.h"
#include "sampler.cl"
#include "camera.cl"
#include "transfer_function.cl"
#include "compositing.cl"

/* Trilinear value of `volume` (dims n) at voxel coordinate x (voxel centres at
 * integers), clamped to the edge voxels. */
inline float eb_uniform_trilinear(__global const float *volume, int4 n, float3 x)
{
    float3 fl = floor(x);
    float3 f = x - fl;
    int3 i0 = convert_int3(fl);
    int x0 = clamp(i0.x, 0, n.x - 1), x1 = clamp(i0.x + 1, 0, n.x - 1);
    int y0 = clamp(i0.y, 0, n.y - 1) * n.x, y1 = clamp(i0.y + 1, 0, n.y - 1) * n.x;
    long nxy = (long)n.x * (long)n.y;
    long z0 = (long)clamp(i0.z, 0, n.z - 1) * nxy, z1 = (long)clamp(i0.z + 1, 0, n.z - 1) * nxy;
    float c00 = mix(volume[z0 + y0 + x0], volume[z0 + y0 + x1], f.x);
    float c10 = mix(volume[z0 + y1 + x0], volume[z0 + y1 + x1], f.x);
    float c01 = mix(volume[z1 + y0 + x0], volume[z1 + y0 + x1], f.x);
    float c11 = mix(volume[z1 + y1 + x0], volume[z1 + y1 + x1], f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

/* One frame of a width x height image, one ray per pixel centre. dt: world step;
 * lattice_lower: lattice position of voxel (0, 0, 0)'s lower corner. */
__kernel void eb_uniform_render(int width, int height, uint seed, int jitter,
                                float4 cam_origin, float4 cam_forward, float4 cam_du, float4 cam_dv,
                                float4 origin_world, float4 inv_spacing, float4 lattice_lower,
                                __global const float *volume, int4 dims,
                                float dt, float inv_unit_distance, float max_opacity,
                                __global const float *tf_xs, __global const float4 *tf_rgba, int tf_n,
                                __global float4 *rgba, __global uint *samples)
{
    int col = get_global_id(0), row = get_global_id(1);
    if (col >= width || row >= height)
        return;
    uint pixel = (uint)row * (uint)width + (uint)col;
    float rho = jitter ? eb_offset(col, row, 0u, seed) : 0.5f;
    float3 dir_world = eb_camera_direction(cam_forward.xyz, cam_du.xyz, cam_dv.xyz,
                                           col, row, width, height, 0.5f, 0.5f);
    float3 org = eb_world_to_lattice(cam_origin.xyz, origin_world.xyz, inv_spacing.xyz);
    float3 dir = dir_world * inv_spacing.xyz;
    /* Voxel coordinates: centres at integers; the support box is [-1, dims]. */
    float3 org_voxel = org - lattice_lower.xyz - 0.5f;
    float2 iv = eb_box_interval((float3)(-1.0f), convert_float3(dims.xyz), org_voxel, 1.0f / dir);
    float t_in = fmax(iv.x, 0.0f), t_out = iv.y;

    eb_ray_state st;
    st.color = (float3)(0.0f);
    st.transmittance = 1.0f;
    st.t_depth = EB_INF;
    st.samples = 0u;
    if (t_out > t_in) {
        eb_intervals it = eb_intervals_start(t_in, t_out, dt, rho);
        float tm, len;
        while (eb_intervals_next(&it, &tm, &len)) {
            float value = eb_uniform_trilinear(volume, dims, org_voxel + tm * dir);
            ++st.samples;
            if (isnan(value))
                continue;
            float4 c = eb_transfer_function(value, tf_xs, tf_rgba, tf_n);
            if (!(c.w > 0.0f))
                continue;
            float a = eb_opacity_correct(c.w, len, inv_unit_distance);
            if (eb_composite(&st, a, c.xyz, tm, max_opacity))
                break;
        }
    }
    rgba[pixel] = (float4)(st.color, 1.0f - st.transmittance);
    samples[pixel] = st.samples;
}
