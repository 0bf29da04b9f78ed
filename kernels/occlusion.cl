/* Ambient occlusion of surface hits (iso-surfaces and slices): `ao_samples`
 * cosine-weighted rays from the hit, each of length `ao_distance` (world),
 * whose visibility is the transmittance of the volume layers along them times
 * (1 - opacity) of every iso-surface, slice and mesh they cross, inside the clip
 * interval. The rays' directions are seeded hashes of (pixel, sample), so
 * the result is reproducible and converges with --spp. (ExaBricks lets only
 * surfaces occlude; the volume's opacity occludes here too.) */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "medium.cl"

/* Below this visibility a ray counts as blocked. */
#define EB_AO_CUTOFF 1e-3f

/* (1 - opacity) of every iso-surface crossed between field values a and b. */
EB_INLINE float eb_transmittance_of_crossings(eb_frame *fr, const float *a, const float *b)
{
    float vis = 1.0f;
    for (int j = 0; j < fr->surf.n_iso; ++j) {
        int f = fr->surf.iso[j].x;
        float iso = fr->surf.iso_value[j].x;
        if ((a[f] < iso) != (b[f] < iso))
            vis *= 1.0f - fr->surf.iso_value[j].y;
    }
    return vis;
}

/* The same between values a and the field at lattice point p (1 where it has no data). */
EB_INLINE float eb_crossings(eb_frame *fr, const float *a, float3 p)
{
    eb_basis_sums s = eb_evaluate(fr, p, 0);
    if (!(s.weight > 0.0f))
        return 1.0f;
    float b[EB_N_FIELDS];
    eb_fields(s, b);
    return eb_transmittance_of_crossings(fr, a, b);
}

/* (1 - opacity) of every mesh hit along world ray org_world + t dir_world, t in
 * (t_min, t_max] (the walk ends once the ray is blocked). */
EB_INLINE float eb_mesh_transmittance(eb_frame *fr, float3 org_world, float3 dir_world,
                                      float t_min, float t_max)
{
    eb_meshes *m = &fr->surf.mesh;
    if (m->n_meshes == 0)
        return 1.0f;
    eb_mesh_ray r = eb_mesh_ray_of(org_world, dir_world);
    float vis = 1.0f, far = t_max;
#define EB_MESH_DIM(i, t)                                                       \
    vis *= 1.0f - m->color[eb_triangle_mesh(m, (i))].w;                         \
    if (!(vis > EB_AO_CUTOFF))                                                  \
        far = -EB_INF;
    EB_MESH_WALK(m, &r, t_min, &far, EB_MESH_DIM);
#undef EB_MESH_DIM
    return vis;
}

/* Visibility along world ray org_world + t dir_world, t in [t_min, t_max]: of the
 * surfaces, and with `medium` of the volume layers too (the path integrator
 * tracks those itself). */
EB_INLINE float eb_visibility(eb_frame *fr, float3 org_world, float3 dir_world,
                              float t_min, float t_max, float rho, const int medium)
{
    float2 keep = eb_clip_interval(fr->clip, org_world, dir_world, t_min);
    t_min = keep.x;
    t_max = fmin(t_max, keep.y);
    if (!(t_max > t_min))
        return 1.0f;
    float vis = eb_mesh_transmittance(fr, org_world, dir_world, t_min, t_max);
    /* Slices: crossed where the plane meets the segment and the field has data. */
    for (int k = 0; k < fr->surf.n_slices; ++k) {
        float3 n = fr->surf.slice_normal[k].xyz;
        float along = dot(dir_world, n);
        if (along == 0.0f)
            continue;
        float t = dot(fr->surf.slice_point[k].xyz - org_world, n) / along;
        if (t > t_min && t < t_max) {
            float3 p = eb_world_to_lattice(org_world + t * dir_world, fr->P->origin_world.xyz,
                                           fr->P->inv_spacing.xyz);
            if (eb_evaluate(fr, p, 0).weight > 0.0f)
                vis *= 1.0f - fr->surf.slice_point[k].w;
        }
    }
    if (!medium && fr->surf.n_iso == 0)
        return vis;  /* nothing in the regions to cross */
    float3 org = eb_world_to_lattice(org_world, fr->P->origin_world.xyz, fr->P->inv_spacing.xyz);
    float3 dir = dir_world * fr->P->inv_spacing.xyz;
    float3 inv_dir = 1.0f / dir;
    /* Without the medium only iso crossings dim the ray: the regions whose range
     * brackets no iso-value are passed over (gaps, as between regions). */
    const uchar want = medium ? EB_SEEN_ANY : EB_SEEN_ISO;
    eb_walk w;
    eb_walk_start(&w, fr->bvh, org, inv_dir, t_min, t_max, want);
    float t_in, t_out, last_exit = t_min;
    float prev[EB_N_FIELDS];
    int prev_valid = 0;
    int r;
    while (vis > EB_AO_CUTOFF && (r = eb_walk_next(&w, fr->bvh, fr->regions, org, inv_dir,
                                                     &t_in, &t_out, want)) >= 0) {
        if (!prev_valid || t_in > last_exit) {
            /* After a gap (or at the start): close the last bracket at the previous
             * exit, then start again from this region's entry. */
            if (prev_valid)
                vis *= eb_crossings(fr, prev, org + last_exit * dir);
            eb_basis_sums s0 = eb_sample_region(fr, r, org + t_in * dir, 0);
            prev_valid = s0.weight > 0.0f;
            if (prev_valid)
                eb_fields(s0, prev);
        }
        last_exit = t_out;
        float dt = ldexp(fr->P->step_base, (int)fr->regions.finest_level[r]);
        eb_intervals it = eb_intervals_start(t_in, t_out, dt, rho);
        float tm, len;
        while (vis > EB_AO_CUTOFF && eb_intervals_next(&it, &tm, &len)) {
            eb_basis_sums s = eb_sample_region(fr, r, org + tm * dir, 0);
            if (!(s.weight > 0.0f)) {
                prev_valid = 0;
                continue;
            }
            float value[EB_N_FIELDS];
            eb_fields(s, value);
            if (prev_valid)
                vis *= eb_transmittance_of_crossings(fr, prev, value);
            for (int f = 0; f < EB_N_FIELDS; ++f)
                prev[f] = value[f];
            prev_valid = 1;
            if (medium && fr->look.n_layers > 0)
                vis *= 1.0f - eb_medium_step(fr, &s, org + tm * dir, 0, value, len, dir_world, 0).w;
        }
    }
    if (prev_valid)  /* the last bracket: up to the end of the last region */
        vis *= eb_crossings(fr, prev, org + last_exit * dir);
    return vis;
}

/* Mean visibility of ao_samples cosine-weighted rays about the unit world
 * normal n from world point p. */
EB_INLINE float eb_ambient_occlusion(eb_frame *fr, float3 p_world, float3 n, uint pixel,
                                     uint sample, uint seed, float rho)
{
    /* Start a little off the surface so that it does not occlude itself. */
    float eps = 1e-3f * fr->P->ao_distance;
    float sum = 0.0f;
    for (int k = 0; k < fr->P->ao_samples; ++k) {
        uint index = sample * (uint)fr->P->ao_samples + (uint)k;
        float2 u = eb_r2(pixel, index, seed, 3u);  /* stratified over the pixel's rays */
        sum += eb_visibility(fr, p_world, eb_sample_cosine(n, u.x, u.y), eps, fr->P->ao_distance, rho, 1);
    }
    return sum / (float)fr->P->ao_samples;
}
