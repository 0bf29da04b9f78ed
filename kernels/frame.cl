/* One frame on the device (the dataset of dataset.cl and the parameters and
 * look of render.cl): the BVH, regions and bricks, the look, surfaces,
 * clipping and lighting, and what every part of the integrator needs from
 * them: the fields (and gradients) at any point. */
#pragma once
#include "common.h"
#include "traversal.cl"
#include "reconstruction.cl"
#include "look.cl"
#include "clipping.cl"
#include "mesh.cl"

/* What a sample reconstructs from: the region's brick list (paper §3.2) or,
 * built with -DEB_CELL_LOCATION, a per-sample descent of a tree over the brick
 * supports (cell_location.cl, the comparison of paper §6.4.2). */
#ifdef EB_CELL_LOCATION
#include "cell_location.cl"
typedef eb_located_bricks eb_sample_bricks;
#else
typedef eb_bricks eb_sample_bricks;
#endif

/* Iso-surfaces and slices (exabricks.scene.IsoSurface, Slice). */
typedef struct {
    __global const int4 *iso;          /* (field, colour field or -1, first knot, knot count) */
    __global const float4 *iso_value;  /* (value, opacity, 0, 0) */
    __global const float4 *iso_color;  /* fixed colour (r, g, b, 0) */
    int n_iso;
    __global const int4 *slice;        /* (field, first knot, knot count, 0) */
    __global const float4 *slice_point;   /* world point, w = opacity */
    __global const float4 *slice_normal;  /* world unit normal */
    int n_slices;
    float tolerance;                   /* iso-hit refinement, world units */
    eb_meshes mesh;                    /* triangle meshes (mesh.cl) */
} eb_surfaces;

typedef struct {
    eb_params_ref P;  /* every scalar of the frame (exabricks.device.kernel_abi.PARAMS),
                            read where it is used: no copies here */
    eb_bvh bvh;
    eb_regions regions;
    eb_sample_bricks bricks;
    eb_look look;
    eb_surfaces surf;
    eb_clip clip;
#ifdef EB_MIXTURE
    __global const float4 *copies;      /* overlapping instances (mixture.cl) */
#endif
#ifdef EB_SHADOW
    __global const float *light;        /* cached transmittance toward the light (light_volume.cl) */
#endif
} eb_frame;

/* The shadow programs' buffer of the cached transmittance (light_volume.cl), as
 * the entries take it (EB_LIGHT_ARGS) and pass it on (EB_LIGHT). */
#ifdef EB_SHADOW
#define EB_LIGHT_ARGS , __global const float *light_volume
#define EB_LIGHT , light_volume
#else
#define EB_LIGHT_ARGS
#define EB_LIGHT
#endif

/* Data-parallel rendering (exabricks.engine.partition): a frame of one domain of a
 * k-d partition of space (P->domain, chosen per frame) takes exactly the samples
 * (and slice hits) at lattice points inside the domain's half-open box, so that
 * the domains' images, composited in visibility order, hold every sample of the
 * whole frame once; a frame of the whole takes every point. */
EB_INLINE int eb_in_domain(eb_frame *fr, float3 p)
{
    return !fr->P->domain
        || (all(p >= fr->P->domain_lower.xyz) && all(p < fr->P->domain_upper.xyz));
}

/* The reconstruction sums at lattice point p in region r. */
EB_INLINE eb_basis_sums eb_sample_region(eb_frame *fr, int r, float3 p, const int grad)
{
#ifdef EB_CELL_LOCATION
    return eb_locate_reconstruct(fr->bricks, p, grad);
#else
    return eb_reconstruct(fr->bricks, fr->regions.brick_ids, fr->regions.brick_start[r],
                          fr->regions.brick_start[r + 1], p, grad);
#endif
}

/* The sums at lattice point p in region r with the bricks seen at `level`
 * (level of detail: exabricks.engine.lod; the finest level otherwise). */
EB_INLINE eb_basis_sums eb_sample_region_at(eb_frame *fr, int r, float3 p, int level,
                                            const int grad)
{
#ifndef EB_CELL_LOCATION
    if (EB_LOD_ON(fr->P) && level > fr->regions.finest_level[r])  /* coarser than the data here */
        return eb_reconstruct_lod(fr->bricks, fr->regions.brick_ids, fr->regions.brick_start[r],
                                  fr->regions.brick_start[r + 1], p, level, grad);
#endif
    return eb_sample_region(fr, r, p, grad);
}

/* The sums a sample of region r takes at lattice point p (level `level`): with
 * the derivative sums where shading uses analytic gradients. */
EB_INLINE eb_basis_sums eb_sample_shaded(eb_frame *fr, int r, float3 p, int level, const int shade)
{
    return (EB_CENTRAL_NORMALS ? 0 : shade) ? eb_sample_region_at(fr, r, p, level, 1)
                                            : eb_sample_region_at(fr, r, p, level, 0);
}

/* The level a region is sampled at: its finest level, or with --lod the
 * coarsest level whose cells project to at most the given pixels at the
 * region's entry distance t (Kähler & Abel), never finer than the data. */
EB_INLINE int eb_sample_level(eb_frame *fr, int r, float t)
{
    int level = fr->regions.finest_level[r];
    if (EB_LOD_ON(fr->P)) {
        float reach = t * fr->P->lod_scale;
        if (reach >= 2.0f)
            level = max(level, min((int)floor(log2(reach)), 30));
    }
    return level;
}

/* The sums at any lattice point p (zero weight outside every region); *level,
 * if given, receives the finest level influencing p (0 if unknown). */
EB_INLINE eb_basis_sums eb_evaluate_at(eb_frame *fr, float3 p, const int grad, int *level)
{
    *level = 0;
#ifdef EB_CELL_LOCATION
    return eb_locate_reconstruct(fr->bricks, p, grad);
#else
    int r = eb_find_region(fr->bvh, fr->regions, p);
    if (r < 0)
        return eb_basis_zero();
    *level = fr->regions.finest_level[r];
    return eb_sample_region(fr, r, p, grad);
#endif
}

EB_INLINE eb_basis_sums eb_evaluate(eb_frame *fr, float3 p, const int grad)
{
    int level;
    return eb_evaluate_at(fr, p, grad, &level);
}

/* Values of every field from the sums s (weight > 0). */
EB_INLINE void eb_fields(eb_basis_sums s, float *value)
{
    for (int f = 0; f < EB_N_FIELDS; ++f)
        value[f] = eb_basis_value(s, f);
}

/* World-scaled gradient of field f at lattice point p (sums s, finest level
 * `level` there): analytic (paper §5.1.2, s must hold the derivative sums),
 * or, where `step` > 0, central differences of the reconstructed field with a
 * step of `step` cells of that level along each lattice axis (the analytic
 * one where a neighbour has no data; EB_CENTRAL_STEP for volume samples,
 * EB_ISO_CENTRAL_STEP for iso hits, where a whole cell averages the
 * reconstruction's cell-scale terraces away). Scaled per field
 * (gradient_scale): only its direction matters. */
EB_INLINE float3 eb_field_gradient_by(eb_frame *fr, eb_basis_sums *s, float3 p, int level, int f,
                                      float step)
{
    float3 g = eb_basis_gradient(*s, f);
    if (step > 0.0f) {
        float h = ldexp(step, level);
        float d[3];
        int ok = 1;
        for (int a = 0; a < 3 && ok; ++a) {
            float3 e = (float3)(a == 0, a == 1, a == 2) * h;
            eb_basis_sums sm = eb_evaluate(fr, p - e, 0), sp = eb_evaluate(fr, p + e, 0);
            ok = sm.weight > 0.0f && sp.weight > 0.0f;
            d[a] = ok ? (eb_basis_value(sp, f) - eb_basis_value(sm, f)) / (2.0f * h) : 0.0f;
        }
        if (ok)
            g = (float3)(d[0], d[1], d[2]);
    }
    return g * fr->look.gradient_scale[f].xyz;
}

/* The gradient of field f as the frame's `gradient` setting says. */
EB_INLINE float3 eb_field_gradient(eb_frame *fr, eb_basis_sums *s, float3 p, int level, int f)
{
    return eb_field_gradient_by(fr, s, p, level, f, EB_CENTRAL_NORMALS ? EB_CENTRAL_STEP : 0.0f);
}

#include "ray.cl"
#include "compositing.cl"
