/* The path integrator (docs/design-rendering.md, "Path tracing"), built with
 * -DEB_PATH: volumetric path tracing of the volume layers lit by the directional
 * light of light.cl (light_dir, light_rgb.xyz) and a uniform environment of
 * radiance light_rgb.w (the ambient term), one path per frame sample.
 *
 * The medium: at a point, layer i of opacity alpha_i per unit distance has the
 * extinction sigma_i = -ln(1 - alpha_i) / unit_distance (alpha capped at
 * EB_PATH_ALPHA_CAP, exabricks.engine.majorants.ALPHA_CAP), the same medium the
 * other integrators march through; the albedo is the extinction-weighted mean
 * of the layers' transfer-function colours. Scattering follows the
 * Henyey-Greenstein phase function of anisotropy g (P->anisotropy), scaled by
 * 4 pi so that g = 0 scatters a light of intensity I into I, as the shadow
 * integrator's samples do.
 *
 * Free paths: delta tracking (Woodcock) through the macrocells of the majorant
 * grid (exabricks.engine.majorants): in each macrocell a tentative collision
 * every -ln(1 - u) / mu, real with probability sigma / mu. Transmittance toward
 * the light and the environment: ratio tracking over the same grid, the
 * product of (1 - sigma / mu) at the tentative collisions, with Russian
 * roulette below EB_PATH_RR_TRANSMITTANCE. Both are unbiased for any majorant
 * that bounds sigma; a tighter one takes fewer null collisions.
 *
 * At each real collision (a scattering event, at most P->bounces of them): the
 * throughput takes the albedo; the light's contribution is added by next-event
 * estimation (phase x transmittance toward it); a new direction is drawn from
 * the phase function; after the last event the environment is estimated along
 * it by its transmittance, else the path goes on, and a path that leaves the
 * medium adds the environment. From the third event on, Russian roulette ends
 * paths of low throughput. A camera ray that leaves the medium without a real
 * collision is transparent: the sample's alpha is 1 at a real collision, so its
 * mean is the opacity 1 - T of the primary ray and the film composites the
 * background behind the rest.
 *
 * Random numbers: a PCG stream per (pixel, sample, seed) (sampler.cl's hash
 * seeds it), so a frame is the same for the same seed on any device. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "path_surfaces.cl"
#ifdef EB_PATH_QUADRATURE
#include "occlusion.cl"
#endif

#ifdef EB_PATH
#define EB_PATH_ALPHA_CAP (1.0f - 9.5367431640625e-7f)  /* 1 - 2^-20 */
#define EB_PATH_RR_TRANSMITTANCE 0.1f
#define EB_PATH_RR_FROM 2      /* Russian roulette of paths after this many events */
#define EB_PATH_MAX_STEPS 1048576  /* tentative collisions of one tracking (a loop bound) */
#define EB_FOUR_PI 12.5663706f

/* The next uniform number in [0, 1) of a PCG-RXS-M-XS stream. */
EB_INLINE float eb_uniform(uint *state)
{
    uint s = *state;
    *state = s * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (float)(((w >> 22u) ^ w) >> 8) * (1.0f / 16777216.0f);
}

/* What tracking counts: real and null collisions of free paths, and the tentative
 * collisions of ratio tracking (each one reconstruction). */
typedef struct {
    uint real, null, ratio;
} eb_path_counts;

/* The majorant grid (exabricks.engine.majorants.MacrocellGrid): mu per macrocell
 * (x fastest, per world unit) from lattice point lower, 1 / width in .w. */
typedef struct {
    __global const float *mu;
    float4 lower;
    int4 n;
} eb_majorants;

/* Extinction per world unit at lattice point p, and the albedo there. */
EB_INLINE float eb_path_sigma(eb_frame *fr, float3 p, float3 *albedo)
{
    eb_basis_sums s = eb_evaluate(fr, p, 0);
    *albedo = (float3)(0.0f);
    if (!(s.weight > 0.0f))
        return 0.0f;
    float value[EB_N_FIELDS];
    eb_fields(s, value);
    eb_look look = fr->look;
    float sum = 0.0f;
    float3 rgb = (float3)(0.0f);
    for (int i = 0; i < look.n_layers; ++i) {
        int4 layer = look.layers[i];
        float4 c = eb_layer_lookup(look, layer, look.table_at[i], value[layer.x]);
        if (!(c.w > 0.0f))
            continue;
        float sigma = -log(1.0f - fmin(c.w, EB_PATH_ALPHA_CAP));
        sum += sigma;
        rgb += sigma * c.xyz;
    }
    if (!(sum > 0.0f))
        return 0.0f;
    *albedo = rgb / sum;
    return sum * fr->P->inv_unit_distance;
}

/* Tracking along world ray o + t d (d unit) over t in [t0, t1] through the majorant
 * grid. ratio == 0 (delta tracking): the distance to the first real collision
 * (its albedo in *albedo), or EB_INF. ratio == 1 (ratio tracking): the
 * transmittance estimate. */
EB_INLINE float eb_track(eb_frame *fr, eb_majorants *m, float3 o, float3 d, float t0, float t1,
                         uint *rng, const int ratio, float3 *albedo, eb_path_counts *count)
{
    float3 org = eb_world_to_lattice(o, fr->P->origin_world.xyz, fr->P->inv_spacing.xyz);
    float3 dir = d * fr->P->inv_spacing.xyz;
    /* The grid's coordinates: macrocell (i, j, k) is [i, i + 1) x ... */
    float3 g0 = (org - m->lower.xyz) * m->lower.w, gd = dir * m->lower.w;
    float3 inv = 1.0f / gd;
    float3 n = convert_float3(m->n.xyz);
    float2 box = eb_box_interval((float3)(0.0f), n, g0, inv);
    float t = fmax(t0, box.x), end = fmin(t1, box.y);
    float transmittance = 1.0f;
    if (!(end > t))
        return ratio ? 1.0f : EB_INF;
    float3 g = g0 + t * gd;
    int3 cell = clamp(convert_int3(floor(g)), (int3)(0), m->n.xyz - 1);
    int3 step = (int3)(gd.x > 0.0f ? 1 : -1, gd.y > 0.0f ? 1 : -1, gd.z > 0.0f ? 1 : -1);
    float3 next = (convert_float3(cell) + (float3)(gd.x > 0.0f, gd.y > 0.0f, gd.z > 0.0f) - g0) * inv;
    next = (float3)(gd.x != 0.0f ? next.x : EB_INF, gd.y != 0.0f ? next.y : EB_INF,
                    gd.z != 0.0f ? next.z : EB_INF);
    float3 delta = fabs(inv);
    int steps = 0;
    while (t < end) {
        float exit = fmin(fmin(fmin(next.x, next.y), next.z), end);
        float mu = m->mu[cell.x + m->n.x * (cell.y + m->n.y * cell.z)];
        if (mu > 0.0f) {
            while (steps++ < EB_PATH_MAX_STEPS) {
                t -= log(1.0f - eb_uniform(rng)) / mu;
                if (t >= exit)
                    break;
                float3 a;
                float sigma = eb_path_sigma(fr, org + t * dir, &a);
                if (ratio) {
                    ++count->ratio;
                    transmittance *= fmax(0.0f, 1.0f - sigma / mu);
                    if (transmittance < EB_PATH_RR_TRANSMITTANCE) {
                        if (eb_uniform(rng) >= 0.5f)
                            return 0.0f;
                        transmittance *= 2.0f;
                    }
                } else if (eb_uniform(rng) * mu < sigma) {
                    ++count->real;
                    *albedo = a;
                    return t;
                } else {
                    ++count->null;
                }
            }
        }
        t = exit;
        if (exit >= end)
            break;
        /* into the next macrocell along the axis whose boundary comes first */
        if (next.x <= next.y && next.x <= next.z) {
            cell.x += step.x;
            next.x += delta.x;
        } else if (next.y <= next.z) {
            cell.y += step.y;
            next.y += delta.y;
        } else {
            cell.z += step.z;
            next.z += delta.z;
        }
        if (any(cell < 0) || any(cell >= m->n.xyz))
            break;
    }
    return ratio ? transmittance : EB_INF;
}

/* Transmittance from world point p along unit d to the end of the medium: of the
 * volume layers by ratio tracking, and of the surfaces crossed (path_surfaces.cl). */
EB_INLINE float eb_path_transmittance(eb_frame *fr, eb_majorants *m, float3 p, float3 d, uint *rng,
                                      eb_path_counts *count)
{
#ifdef EB_PATH_QUADRATURE
    /* the shadow integrator's integration instead (benchmarks/bench_shadow_rays.py) */
    return eb_visibility(fr, p, d, 0.0f, EB_INF, eb_uniform(rng), 1);
#else
    float2 keep = eb_clip_interval(fr->clip, p, d, 0.0f);
    float3 unused;
    float t = keep.y > keep.x ? eb_track(fr, m, p, d, keep.x, keep.y, rng, 1, &unused, count) : 1.0f;
#ifdef EB_SURFACES
    if (t > 0.0f)
        t *= eb_surfaces_transmittance(fr, p, d, eb_uniform(rng));
#endif
    return t;
#endif
}

/* The Henyey-Greenstein phase function times 4 pi at cos(angle) c between the
 * direction of travel and the scattered direction. */
EB_INLINE float eb_phase(float c, float g)
{
    float denom = 1.0f + g * g - 2.0f * g * c;
    return (1.0f - g * g) / (denom * sqrt(denom));
}

/* A direction scattered from unit d by the Henyey-Greenstein phase function. */
EB_INLINE float3 eb_sample_phase(float3 d, float g, uint *rng)
{
    float u1 = eb_uniform(rng), u2 = eb_uniform(rng);
    float c;
    if (fabs(g) < 1e-3f) {
        c = 1.0f - 2.0f * u1;
    } else {
        float s = (1.0f - g * g) / (1.0f - g + 2.0f * g * u1);
        c = (1.0f + g * g - s * s) / (2.0f * g);
    }
    c = clamp(c, -1.0f, 1.0f);
    float sine = sqrt(fmax(0.0f, 1.0f - c * c)), phi = 6.28318531f * u2;
    float3 t, b;
    eb_orthonormal(d, &t, &b);
    return normalize(sine * cos(phi) * t + sine * sin(phi) * b + c * d);
}

/* The surface `hit` met at world point x coming along d (path_surfaces.cl): its
 * normals turned toward where the path came from, and the directional light
 * it reflects back along -d added to *radiance (times `throughput`). */
#ifdef EB_SURFACES
EB_INLINE void eb_path_surface_light(eb_frame *fr, eb_majorants *m, eb_surface *hit, float3 x,
                                     float3 d, float3 throughput, float3 *radiance, uint *rng,
                                     eb_path_counts *count)
{
    eb_face(&hit->n, &hit->ns, d);
    eb_params_ref P = fr->P;
    float3 l = P->light_dir.xyz;
    float c = dot(hit->ns, l);
    if (c > 0.0f && any(P->light_rgb.xyz > 0.0f)) {
        float vis = eb_path_transmittance(fr, m, eb_off_surface(P, x, hit->n, l), l, rng, count);
        *radiance += throughput * vis * P->light_rgb.xyz * (hit->rgb * c + eb_highlight(P, hit->ns, l, d));
    }
}
#endif

/* One path from the camera ray `ray`: premultiplied radiance (xyz) and alpha (w);
 * *samples counts its reconstructions, *depth is the distance to its first real
 * collision or surface met (infinity if none), and `counts` (real, null, ratio)
 * are added to. */
EB_INLINE float4 eb_path(eb_frame *fr, eb_ray *ray, __global const float *look_f, uint *samples,
                         float *depth, __global uint *counts)
{
    eb_params_ref P = fr->P;
    eb_majorants m = {look_f + P->majorant_at, P->majorant_lower, P->majorant_dims};
    uint rng = eb_hash(eb_shift(ray->pixel, ray->seed, 7u) + ray->sample * EB_GOLDEN);
    eb_path_counts count = {0u, 0u, 0u};
    float3 o = ray->org_world, d = ray->dir_world;
    float3 radiance = (float3)(0.0f), throughput = (float3)(1.0f);
    float3 light = P->light_dir.xyz, light_rgb = P->light_rgb.xyz;
    float ambient = P->light_rgb.w, g = P->anisotropy, alpha = 0.0f;
    *depth = EB_INF;
    float travelled = 0.0f;  /* along the camera ray, to the last surface passed through */
#ifdef EB_SURFACES
    float skip = 0.0f;  /* past a surface passed through */
    int crossings = 0;
#endif
    for (int event = 0; event < P->bounces;) {
        float2 keep = eb_clip_interval(fr->clip, o, d, 0.0f);
        float3 albedo;
        float t = keep.y > keep.x ? eb_track(fr, &m, o, d, keep.x, keep.y, &rng, 0, &albedo, &count)
                                  : EB_INF;
#ifdef EB_SURFACES
        /* Surfaces before the medium's collision (free paths are memoryless, so
         * tracking the whole segment first is tracking up to the surface) */
        int sj, sk;
        float ts = keep.y > keep.x ? eb_nearest_surface(fr, o, d, fmax(keep.x, skip), fmin(keep.y, t),
                                                        eb_uniform(&rng), &sj, &sk)
                                   : EB_INF;
        skip = 0.0f;
        eb_surface hit;
        if (ts < t) {  /* a surface: met with probability a, else passed */
            float3 x = o + ts * d;
            hit = eb_surface_at(fr, eb_world_to_lattice(x, P->origin_world.xyz, P->inv_spacing.xyz),
                                x, sj, sk);
            if (!(eb_uniform(&rng) < hit.a)) {
                if (++crossings > EB_PATH_MAX_CROSSINGS)
                    break;
                o = x;
                skip = EB_PATH_PASS * P->light_dir.w;
                if (event == 0)
                    travelled += ts;
                continue;
            }
            t = ts;
        } else {
            hit.a = 0.0f;
        }
#endif
        if (t == EB_INF) {  /* out of the medium: the environment */
            if (event > 0)
                radiance += throughput * ambient;
            break;
        }
        if (event == 0) {
            alpha = 1.0f;
            *depth = travelled + t;
        }
        o += t * d;
#ifdef EB_SURFACES
        if (hit.a > 0.0f) {  /* Lambertian: on along a cosine-weighted direction */
            eb_path_surface_light(fr, &m, &hit, o, d, throughput, &radiance, &rng, &count);
            throughput *= hit.rgb;
            float u1 = eb_uniform(&rng), u2 = eb_uniform(&rng);
            d = eb_sample_cosine(hit.ns, u1, u2);
            if (!(dot(d, hit.n) > 0.0f))
                break;  /* below the surface (a mesh's smooth normal tilted from its own) */
            o += P->light_dir.w * hit.n;
        } else
#endif
        {
            throughput *= albedo;
            if (any(light_rgb > 0.0f))
                radiance += throughput * light_rgb * (eb_phase(dot(d, light), g)
                                                      * eb_path_transmittance(fr, &m, o, light, &rng, &count));
            d = eb_sample_phase(d, g, &rng);
        }
        if (++event == P->bounces) {  /* the last event: the environment along d */
            if (ambient > 0.0f)
                radiance += throughput * ambient * eb_path_transmittance(fr, &m, o, d, &rng, &count);
            break;
        }
        float most = fmax(fmax(throughput.x, throughput.y), throughput.z);
        if (event > EB_PATH_RR_FROM && most < 1.0f) {
            float survive = fmin(most, 0.95f);
            if (eb_uniform(&rng) >= survive)
                break;
            throughput /= survive;
        }
    }
    *samples = count.real + count.null + count.ratio;
    if (count.real)
        atomic_add(&counts[0], count.real);
    if (count.null)
        atomic_add(&counts[1], count.null);
    if (count.ratio)
        atomic_add(&counts[2], count.ratio);
    return (float4)(radiance, alpha);
}
#endif
