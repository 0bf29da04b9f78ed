/* Surfaces met by paths (docs/design-rendering.md, "Path tracing"), built with
 * -DEB_PATH -DEB_SURFACES: iso-surfaces, slices and meshes inside the medium.
 *
 * A path segment ends at the nearest of a real collision in the medium and a
 * surface (eb_nearest_surface): iso crossings found as a primary ray finds
 * them (surfaces.cl: brackets between the samples of each region's finest
 * level at the sampling rate, from a random offset, refined by bisection),
 * slices where the field has data, the nearest mesh triangle. A surface of
 * opacity a is met with probability a (else the path goes on through it), so
 * its expected share is the emission-absorption integrators' a x colour. At a
 * surface met, the light is that of the shadow integrator's surface hits
 * (light.cl): colour x cos toward the directional light, plus the Blinn-Phong
 * highlight, times the transmittance toward it; the path then goes on
 * diffusely (a cosine-weighted direction about the shading normal, the
 * throughput taking the colour: a Lambertian surface of albedo colour, so a
 * white surface under a uniform environment A alone is A). The highlight is the
 * directional light's only. Shadow and bounce rays start off the surface along
 * its normal by light_dir.w, as the shadow integrator's do. The transmittance
 * toward a light or the environment takes (1 - a) of every surface crossed
 * (occlusion.cl's eb_visibility without the medium, which ratio tracking
 * estimates). */
#pragma once
#include "common.h"
#include "frame.cl"
#include "sampler.cl"

#if defined(EB_PATH) && defined(EB_SURFACES)
#include "surfaces.cl"

/* A path that passes through a surface goes on from this far past it, so that it
 * does not meet it again: a fiftieth of the shadow rays' offset light_dir.w (half a
 * finest cell, picture/light.py), ten times the iso-surfaces' tolerance. */
#define EB_PATH_PASS 0.02f
/* Surfaces a path passes through at most (a loop bound). */
#define EB_PATH_MAX_CROSSINGS 64

/* The nearest surface along world ray o + t d (d unit) inside (t0, t1]: its
 * distance (EB_INF: none), with *j the iso-surface (else -1) and *k the slice, or
 * -1 - the mesh triangle; iso crossings between samples at offset rho. */
EB_INLINE float eb_nearest_surface(eb_frame *fr, float3 o, float3 d, float t0, float t1, float rho,
                                   int *j, int *k)
{
    float best = t1;
    int found = 0;
    *j = -1;
    *k = 0;
    for (int s = 0; s < fr->surf.n_slices && s < EB_MAX_SLICES; ++s) {
        float3 n = fr->surf.slice_normal[s].xyz;
        float along = dot(d, n);
        if (along == 0.0f)
            continue;
        float t = dot(fr->surf.slice_point[s].xyz - o, n) / along;
        if (!(t > t0 && t <= best))
            continue;
        float3 p = eb_world_to_lattice(o + t * d, fr->P->origin_world.xyz, fr->P->inv_spacing.xyz);
        if (eb_evaluate(fr, p, 0).weight > 0.0f) {
            best = t;
            *k = s;
            found = 1;
        }
    }
    eb_meshes *m = &fr->surf.mesh;
    if (m->n_meshes > 0) {
        eb_mesh_ray r = eb_mesh_ray_of(o, d);
        int nearest = -1;
#define EB_MESH_NEAREST(i, t)                                                   \
    if ((t) <= best) {                                                          \
        best = (t);                                                             \
        nearest = (i);                                                          \
    }
        EB_MESH_WALK(m, &r, t0, &best, EB_MESH_NEAREST);
#undef EB_MESH_NEAREST
        if (nearest >= 0) {
            *k = -1 - nearest;
            found = 1;
        }
    }
    if (fr->surf.n_iso > 0) {
        eb_ray ray;
        ray.org = eb_world_to_lattice(o, fr->P->origin_world.xyz, fr->P->inv_spacing.xyz);
        ray.dir = d * fr->P->inv_spacing.xyz;
        ray.inv_dir = 1.0f / ray.dir;
        /* Only regions whose value range brackets an iso-value can hold a crossing
         * (a skipped one is a gap: the bracket closes at the last exit). */
        eb_walk w;
        eb_walk_start(&w, fr->bvh, ray.org, ray.inv_dir, t0, best, EB_SEEN_ISO);
        float t_in, t_out, last_exit = t0, prev_t = t0, tm, len;
        float prev[EB_N_FIELDS], value[EB_N_FIELDS];
        int prev_valid = 0, r, valid = 0;
        /* Brackets [prev_t, tm] in distance order; the first one crossed holds the
         * nearest crossing. A gap closes the bracket at the last region's exit. */
#define EB_BRACKET(t_b)                                                                  \
    if (prev_valid && valid) {                                                           \
        float t_hit = EB_INF;                                                            \
        for (int i = 0; i < fr->surf.n_iso; ++i) {                                       \
            int f = fr->surf.iso[i].x;                                                   \
            float iso = fr->surf.iso_value[i].x, da = prev[f] - iso, db = value[f] - iso; \
            if ((da < 0.0f) == (db < 0.0f))                                              \
                continue;                                                                \
            float t = eb_refine_crossing(fr, &ray, f, iso, prev_t, da, (t_b), db);       \
            if (t < t_hit && t > t0) {                                                   \
                t_hit = t;                                                               \
                *j = i;                                                                  \
            }                                                                            \
        }                                                                                \
        if (t_hit < EB_INF)                                                              \
            return t_hit;                                                                \
    }                                                                                    \
    prev_valid = valid;                                                                  \
    prev_t = (t_b);                                                                      \
    for (int f = 0; f < EB_N_FIELDS; ++f)                                                \
        prev[f] = value[f];
        while ((r = eb_walk_next(&w, fr->bvh, fr->regions, ray.org, ray.inv_dir, &t_in, &t_out,
                                 EB_SEEN_ISO)) >= 0) {
            if (t_in > last_exit || !prev_valid) {
                if (prev_valid) {  /* close the bracket at the previous exit */
                    eb_basis_sums s = eb_evaluate(fr, ray.org + last_exit * ray.dir, 0);
                    valid = s.weight > 0.0f;
                    eb_fields(s, value);
                    EB_BRACKET(last_exit)
                }
                eb_basis_sums s0 = eb_sample_region(fr, r, ray.org + t_in * ray.dir, 0);
                valid = s0.weight > 0.0f;
                eb_fields(s0, value);
                prev_valid = 0;
                EB_BRACKET(t_in)
            }
            last_exit = t_out;
            float dt = ldexp(fr->P->step_base, (int)fr->regions.finest_level[r]);
            eb_intervals it = eb_intervals_start(t_in, t_out, dt, rho);
            while (eb_intervals_next(&it, &tm, &len)) {
                eb_basis_sums s = eb_sample_region(fr, r, ray.org + tm * ray.dir, 0);
                valid = s.weight > 0.0f;
                eb_fields(s, value);
                EB_BRACKET(tm)
            }
        }
        if (prev_valid) {  /* the last bracket: up to the end of the last region */
            eb_basis_sums s = eb_evaluate(fr, ray.org + last_exit * ray.dir, 0);
            valid = s.weight > 0.0f;
            eb_fields(s, value);
            EB_BRACKET(last_exit)
        }
#undef EB_BRACKET
        *j = -1;
    }
    return found ? best : EB_INF;
}

/* (1 - a) of every surface along world ray p + t d, t > 0 (inside the clip region). */
EB_INLINE float eb_surfaces_transmittance(eb_frame *fr, float3 p, float3 d, float rho)
{
    return eb_visibility(fr, p, d, 0.0f, EB_INF, rho, 0);
}

#endif
