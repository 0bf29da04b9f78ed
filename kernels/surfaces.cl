/* Iso-surfaces and slices along a ray (docs/design-rendering.md, "Surfaces, slices and clipping").
 *
 * Iso-surfaces live on the basis field. A crossing of iso-value v on field f
 * is detected between consecutive samples of the adaptive sampling (values on
 * both sides of v), across region boundaries too. Where the walk leaves a gap
 * (a skipped region, the end of the clip interval or of the data) the bracket
 * is closed by evaluating the field at the last region's exit, and the next
 * region starts from its entry point. The crossing is then
 * refined by bisection on the reconstructed field (any point: the BVH finds
 * its region) to within `tolerance` (1e-3 of a finest cell), and placed by
 * linear interpolation in the last bracket. What can still be missed: two
 * crossings of the same value between two samples (a shell thinner than a
 * sample step). Any number of iso-values (EB_MAX_ISO) on any
 * fields; the hits between two samples are composited in distance order.
 *
 * Slices: planes (world point and normal) that show a colour map of a field
 * where it has data; their distances along the ray are found once per ray.
 *
 * A surface hit is shaded with the normal from the gradient (iso) or the plane
 * (slice), flipped toward the viewer: headlight diffuse (EB_AMBIENT +
 * EB_DIFFUSE |n . v|) plus an optional Blinn-Phong term specular |n . v|^shininess
 * (the half vector of a headlight is the view direction), or under the shadow
 * integrator the directional light's (light.cl), times the ambient occlusion;
 * it composites as C += T a rgb, T *= 1 - a. The volume in front of it (up to
 * the previous sample) is integrated first. */
#pragma once
#include "common.h"
#include "frame.cl"

#ifdef EB_SURFACES
#include "occlusion.cl"
#include "light.cl"

/* Bisection steps at most: from any sample step down to the tolerance. */
#define EB_REFINE_STEPS 40

/* Insert a hit at distance t (slice k >= 0, or mesh triangle -1 - k) into the
 * ray's list, kept sorted by distance; when it holds `most`, the farthest goes. */
EB_INLINE void eb_hit_insert(eb_ray_state *st, float t, int k, int most)
{
    int i;
    if (st->n_slices < most)
        i = st->n_slices++;
    else if (t < st->slice_t[most - 1])
        i = most - 1;
    else
        return;
    for (; i > 0 && st->slice_t[i - 1] > t; --i) {
        st->slice_t[i] = st->slice_t[i - 1];
        st->slice_k[i] = st->slice_k[i - 1];
    }
    st->slice_t[i] = t;
    st->slice_k[i] = k;
}

/* Whether the list already holds a hit of the same mesh at the same distance
 * (to 1e-6 of it): a ray through an edge or a vertex hits every triangle there
 * (the test is watertight), and one surface is crossed once. */
EB_INLINE int eb_mesh_seen(eb_ray_state *st, eb_meshes *m, int i, float t)
{
    int mesh = eb_triangle_mesh(m, i);
    for (int h = 0; h < st->n_slices; ++h) {
        int k = st->slice_k[h];
        if (k < 0 && fabs(st->slice_t[h] - t) <= 1e-6f * t && eb_triangle_mesh(m, -1 - k) == mesh)
            return 1;
    }
    return 0;
}

/* The nearest EB_MAX_MESH_HITS mesh hits inside (t0, t1] into the ray's list
 * after its slices: the walk is pruned beyond the farthest kept hit once the
 * list is full, and beyond the first opaque hit, whose distance it returns
 * (+inf: none). A frame split by space has no meshes (the host refuses them,
 * exabricks.parallel.needs_image_mode), and an instance's domain is all of
 * space (exabricks.engine.instances), so no hit is another domain's. */
EB_INLINE float eb_mesh_hits(eb_frame *fr, eb_ray *ray, float t0, float t1, eb_ray_state *st)
{
    eb_meshes *m = &fr->surf.mesh;
    float opaque = EB_INF;
    if (m->n_meshes == 0)
        return opaque;
    int most = st->n_slices + EB_MAX_MESH_HITS;
    eb_mesh_ray r = eb_mesh_ray_of(ray->org_world, ray->dir_world);
    float far = t1;
#define EB_MESH_TAKE(i, t)                                                      \
    if (!eb_mesh_seen(st, m, (i), (t))) {                                       \
        eb_hit_insert(st, (t), -1 - (i), most);                                 \
        if (m->color[eb_triangle_mesh(m, (i))].w >= 1.0f) {                     \
            far = fmin(far, (t));                                               \
            opaque = fmin(opaque, (t));                                         \
        }                                                                       \
        if (st->n_slices == most)                                               \
            far = fmin(far, st->slice_t[most - 1]);                             \
    }
    EB_MESH_WALK(m, &r, t0, &far, EB_MESH_TAKE);
#undef EB_MESH_TAKE
    return opaque;
}

/* The slices the ray crosses inside [t0, t1] and its nearest mesh hits, sorted
 * by distance into `st`; returns the distance of the first opaque mesh hit
 * (+inf: none), where the volume behind it ends. */
EB_INLINE float eb_slices_start(eb_frame *fr, eb_ray *ray, float t0, float t1, eb_ray_state *st)
{
    st->n_slices = 0;
    st->next_slice = 0;
    for (int k = 0; k < fr->surf.n_slices && k < EB_MAX_SLICES; ++k) {
        float3 n = fr->surf.slice_normal[k].xyz;
        float along = dot(ray->dir_world, n);
        if (along == 0.0f)
            continue;
        float t = dot(fr->surf.slice_point[k].xyz - ray->org_world, n) / along;
        if (!(t >= t0 && t <= t1))
            continue;
        if (!eb_in_domain(fr, ray->org + t * ray->dir))
            continue;  /* another domain's hit */
        eb_hit_insert(st, t, k, EB_MAX_SLICES);
    }
    return eb_mesh_hits(fr, ray, t0, t1, st);
}

/* Where field f crosses iso between ta and tb, given da = B(ta) - iso and
 * db = B(tb) - iso of opposite signs. A point without data shrinks the bracket
 * toward its front (the crossing nearest the eye is wanted). */
EB_COLD float eb_refine_crossing(eb_frame *fr, eb_ray *ray, int f, float iso,
                                 float ta, float da, float tb, float db)
{
    for (int i = 0; i < EB_REFINE_STEPS && tb - ta > fr->surf.tolerance; ++i) {
        float tm = 0.5f * (ta + tb);
        eb_basis_sums s = eb_evaluate(fr, ray->org + tm * ray->dir, 0);
        if (!(s.weight > 0.0f)) {
            tb = tm;
            continue;
        }
        float dm = eb_basis_value(s, f) - iso;
        if ((dm < 0.0f) == (da < 0.0f)) {
            ta = tm;
            da = dm;
        } else {
            tb = tm;
            db = dm;
        }
    }
    return da != db ? ta + (tb - ta) * (da / (da - db)) : 0.5f * (ta + tb);
}

/* Normal n (any length and side) and shading normal ns (on n's side) of a hit seen
 * along unit d, made unit and turned toward where d comes from (a zero normal
 * faces -d). */
EB_INLINE void eb_face(float3 *n, float3 *ns, float3 d)
{
    float n2 = dot(*n, *n), s2 = dot(*ns, *ns);
    float3 u = n2 > 0.0f ? *n * rsqrt(n2) : -d;
    float3 v = s2 > 0.0f ? *ns * rsqrt(s2) : u;
    if (dot(u, d) > 0.0f) {
        u = -u;
        v = -v;
    }
    *n = u;
    *ns = v;
}

/* Where a ray toward l leaves surface point x of unit normal n: off the surface by
 * light_dir.w along n, on l's side, so that a ray grazing the surface meets
 * neither its cell-scale bumps nor the surface itself. */
EB_INLINE float3 eb_off_surface(eb_params_ref P, float3 x, float3 n, float3 l)
{
    float bias = P->light_dir.w;
    return x + (dot(n, l) >= 0.0f ? bias : -bias) * n;
}

/* The Blinn-Phong highlight of a light toward l on shading normal ns seen along d
 * (about the half vector of l and -d), 0 without `specular`. */
EB_INLINE float eb_highlight(eb_params_ref P, float3 ns, float3 l, float3 d)
{
    return P->specular > 0.0f ? P->specular * pow(fmax(dot(ns, normalize(l - d)), 0.0f), P->shininess)
                              : 0.0f;
}

/* Composite a surface hit at distance t of normal n (any length and side) and
 * shading normal ns (on n's side; a mesh's smooth normal, else n), colour rgb
 * and opacity a: headlight and specular from ns, ambient occlusion about n. */
EB_INLINE int eb_shade_hit(eb_frame *fr, eb_ray *ray, eb_ray_state *st, float t, float3 n,
                           float3 ns, float3 rgb, float a)
{
    if (!(a > 0.0f))
        return 0;
    eb_face(&n, &ns, ray->dir_world);
#ifdef EB_SHADOW
    {  /* the directional light (light.cl) */
        float3 l = fr->P->light_dir.xyz;
        float c = dot(ns, l);
        float3 lit = (float3)(fr->P->light_rgb.w), shine = (float3)(0.0f);
        if (c > 0.0f) {
            float3 x = eb_off_surface(fr->P, ray->org_world + t * ray->dir_world, n, l);
            float vis = eb_light_transmittance(fr, x, ray->rho);
            lit += vis * c * fr->P->light_rgb.xyz;
            shine = vis * eb_highlight(fr->P, ns, l, ray->dir_world) * fr->P->light_rgb.xyz;
        }
        rgb = rgb * lit + shine;
    }
#else
    if (fr->P->shading) {
        float c = fmax(-dot(ns, ray->dir_world), 0.0f);
        rgb = rgb * (EB_AMBIENT + EB_DIFFUSE * c);
        if (fr->P->specular > 0.0f)
            rgb += fr->P->specular * pow(c, fr->P->shininess);
    }
#endif
    if (fr->P->ao_samples > 0)
        rgb *= eb_ambient_occlusion(fr, ray->org_world + t * ray->dir_world, n, ray->pixel,
                                    ray->sample, ray->seed, ray->rho);
    if (a >= 1.0f && st->t_opaque == EB_INF)
        st->t_opaque = t;
    return eb_composite(st, a, rgb, t, fr->P->max_opacity);
}

/* Colour, opacity, normal and shading normal of mesh triangle i hit at lattice
 * point p, world point x: the mesh's colour, or its colour map of a field where
 * that field has data. */
EB_INLINE float4 eb_mesh_look(eb_frame *fr, int i, float3 p, float3 x, float3 *n, float3 *ns)
{
    eb_meshes *m = &fr->surf.mesh;
    int k = eb_triangle_mesh(m, i);
    float4 c = m->color[k];
    int4 info = m->info[k];
    *n = eb_triangle_normal(m, i);
    *ns = eb_triangle_shading_normal(m, i, x);
    if (dot(*ns, *n) < 0.0f)
        *ns = -*ns;
    if (info.x >= 0) {
        eb_basis_sums s = eb_evaluate(fr, p, 0);
        if (s.weight > 0.0f)
            c.xyz = eb_lookup(fr->look, info.y, info.z, eb_basis_value(s, info.x)).xyz;
    }
    return c;
}

/* What a surface hit shows: its normal n (any length and side), its shading
 * normal ns (on n's side: a mesh's smooth normal, else n), colour and opacity
 * (a = 0: nothing, as where the field has no data). */
typedef struct {
    float3 n, ns, rgb;
    float a;
} eb_surface;

/* The surface hit at lattice point p, world point x: iso-surface j (k < 0), slice
 * k (j < 0), or mesh triangle -1 - k (j < 0, k < 0). */
EB_INLINE eb_surface eb_surface_at(eb_frame *fr, float3 p, float3 x, int j, int k)
{
    eb_surface hit;
    if (j < 0 && k < 0) {
        float4 c = eb_mesh_look(fr, -1 - k, p, x, &hit.n, &hit.ns);
        hit.rgb = c.xyz;
        hit.a = c.w;
        return hit;
    }
    int level;
    eb_basis_sums s = eb_evaluate_at(fr, p, 1, &level);
    hit.a = 0.0f;
    if (!(s.weight > 0.0f))
        return hit;  /* no data here: nothing to draw */
    float value[EB_N_FIELDS];
    eb_fields(s, value);
    if (j >= 0) {
        int4 iso = fr->surf.iso[j];
        hit.n = eb_field_gradient_by(fr, &s, p, level, iso.x,
                                     EB_CENTRAL_NORMALS || fr->P->iso_gradient == EB_ISO_GRADIENT_CENTRAL
                                         || fr->P->reconstruction == EB_RECONSTRUCTION_NEAREST
                                         ? EB_ISO_CENTRAL_STEP : 0.0f);
        hit.rgb = iso.y >= 0 ? eb_lookup(fr->look, iso.z, iso.w, value[iso.y]).xyz
                             : fr->surf.iso_color[j].xyz;
        hit.a = fr->surf.iso_value[j].y;
    } else {
        int4 slice = fr->surf.slice[k];
        hit.n = fr->surf.slice_normal[k].xyz;
        hit.rgb = eb_lookup(fr->look, slice.y, slice.z, value[slice.x]).xyz;
        hit.a = fr->surf.slice_point[k].w;
    }
    hit.ns = hit.n;
    return hit;
}

/* Shade and composite one surface hit at distance t (eb_surface_at's j and k).
 * Returns 1 once the ray is opaque enough to stop. */
EB_COLD int eb_surface_hit(eb_frame *fr, eb_ray *ray, eb_ray_state *st, float t, int j, int k)
{
    eb_surface hit = eb_surface_at(fr, ray->org + t * ray->dir, ray->org_world + t * ray->dir_world, j, k);
    return eb_shade_hit(fr, ray, st, t, hit.n, hit.ns, hit.rgb, hit.a);
}

/* Composite every surface hit before distance t_limit: iso crossings between
 * the previous sample and this one (field values `value`, valid if it has
 * data) and slices, in distance order; then this sample becomes the previous
 * one. Returns 1 once the ray is opaque enough to stop. */
EB_INLINE int eb_surfaces_until(eb_frame *fr, eb_ray *ray, eb_ray_state *st, float t_limit,
                                const float *value, int valid)
{
    float hit_t[EB_MAX_ISO];
    int hit_j[EB_MAX_ISO];
    int n_hits = 0;
    if (valid && st->prev_valid) {
        for (int j = 0; j < fr->surf.n_iso; ++j) {
            int f = fr->surf.iso[j].x;
            float iso = fr->surf.iso_value[j].x;
            float da = st->prev[f] - iso, db = value[f] - iso;
            if ((da < 0.0f) == (db < 0.0f))
                continue;
            float t = eb_refine_crossing(fr, ray, f, iso, st->prev_t, da, t_limit, db);
            int i = n_hits++;
            for (; i > 0 && hit_t[i - 1] > t; --i) {
                hit_t[i] = hit_t[i - 1];
                hit_j[i] = hit_j[i - 1];
            }
            hit_t[i] = t;
            hit_j[i] = j;
        }
    }
    for (int h = 0; h < n_hits || st->next_slice < st->n_slices;) {
        int iso_next = h < n_hits;
        int slice_next = st->next_slice < st->n_slices;
        float ti = iso_next ? hit_t[h] : EB_INF;
        float ts = slice_next ? st->slice_t[st->next_slice] : EB_INF;
        if (!(fmin(ti, ts) <= t_limit))
            break;
        int done;
        if (iso_next && (!slice_next || ti <= ts)) {
            done = eb_surface_hit(fr, ray, st, ti, hit_j[h++], -1);
        } else {
            done = eb_surface_hit(fr, ray, st, ts, -1, st->slice_k[st->next_slice++]);
        }
        if (done)
            return 1;
    }
    st->prev_valid = valid;
    if (valid) {
        st->prev_t = t_limit;
        for (int f = 0; f < EB_N_FIELDS; ++f)
            st->prev[f] = value[f];
    }
    return 0;
}

/* Close the open bracket at the last region's exit (before a gap, and at the
 * end of the walk): the field there ends the crossing test of the last
 * samples. Returns 1 once the ray is opaque enough to stop. */
EB_COLD int eb_close_bracket(eb_frame *fr, eb_ray *ray, eb_ray_state *st)
{
    if (fr->surf.n_iso == 0 || !st->prev_valid || !(st->last_exit > st->prev_t))
        return 0;
    eb_basis_sums s = eb_evaluate(fr, ray->org + st->last_exit * ray->dir, 0);
    float value[EB_N_FIELDS];
    int valid = s.weight > 0.0f;
    if (valid)
        eb_fields(s, value);
    return eb_surfaces_until(fr, ray, st, st->last_exit, value, valid);
}

/* At the entry of region r ([t_in, t_out]): close the open bracket after a gap,
 * and start the crossing test at the region's entry (after a gap, or the first
 * region). Returns 1 once the ray is opaque enough to stop. */
EB_INLINE int eb_surfaces_enter_region(eb_frame *fr, eb_ray *ray, int r, float t_in, float t_out,
                                       eb_ray_state *st)
{
    if (t_in > st->last_exit && eb_close_bracket(fr, ray, st))
        return 1;
    if (fr->surf.n_iso > 0 && (!st->prev_valid || t_in > st->last_exit)) {
        eb_basis_sums s0 = eb_sample_region(fr, r, ray->org + t_in * ray->dir, 0);
        st->prev_valid = s0.weight > 0.0f;
        st->prev_t = t_in;
        for (int f = 0; f < EB_N_FIELDS; ++f)
            st->prev[f] = eb_basis_value(s0, f);
    }
    st->last_exit = t_out;
    return 0;
}
#else
/* A frame without iso-surfaces or slices (no -DEB_SURFACES): nothing to do, and
 * the compiler drops the calls. */
EB_INLINE float eb_slices_start(eb_frame *fr, eb_ray *ray, float t0, float t1, eb_ray_state *st)
{
    return EB_INF;
}

EB_INLINE int eb_surfaces_until(eb_frame *fr, eb_ray *ray, eb_ray_state *st, float t_limit,
                                const float *value, int valid)
{
    return 0;
}

EB_INLINE int eb_close_bracket(eb_frame *fr, eb_ray *ray, eb_ray_state *st)
{
    return 0;
}

EB_INLINE int eb_surfaces_enter_region(eb_frame *fr, eb_ray *ray, int r, float t_in, float t_out,
                                       eb_ray_state *st)
{
    return 0;
}
#endif
