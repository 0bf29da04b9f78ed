/* The participating medium: any number of volume layers, each a field with its
 * own transfer function, mixed per step (docs/design-rendering.md, "Transfer
 * functions and volume layers"). Layer i has slab opacity alpha_i per unit_distance, extinction
 * sigma_i = -ln(1 - alpha_i) / unit_distance; a step of length dt has opacity
 * 1 - exp(-sum_i sigma_i dt) and colour sum_i sigma_i rgb_i / sum_i sigma_i.
 * Computed in base 2 (s_i = -log2(1 - alpha_i), the factor ln 2 cancels) with
 * the inlined polynomials of transfer_function.cl; one layer takes exactly the
 * single-field path 1 - (1 - alpha)^(dt / unit_distance) (paper §4.3).
 * eb_medium_step computes a field's gradient only when a layer of it is
 * visible and shaded. */
#pragma once
#include "common.h"
#include "frame.cl"

/* Media mixed at one point: their extinctions add, their colours weighted by
 * extinction; a medium of opacity 1 (infinite extinction) alone gives the
 * colour (with others like it: their mean). Also the copies of overlapping
 * instances (mixture.cl). */
typedef struct {
    float s_sum;  /* sum of -log2(1 - alpha) */
    float3 rgb, rgb_opaque;
    int opaque;
} eb_extinctions;

EB_INLINE eb_extinctions eb_extinctions_none(void)
{
    eb_extinctions m = {0.0f, (float3)(0.0f), (float3)(0.0f), 0};
    return m;
}

/* Add a medium of opacity a (> 0, per the unit the result scales) and colour rgb. */
EB_INLINE void eb_extinctions_add(eb_extinctions *m, float a, float3 rgb)
{
    if (a >= 1.0f) {
        m->rgb_opaque += rgb;
        ++m->opaque;
        return;
    }
    float s = -eb_log2_positive(1.0f - a);
    m->s_sum += s;
    m->rgb += s * rgb;
}

/* Colour (xyz) and opacity (w) of the mixture over `scale` units; zero if none. */
EB_INLINE float4 eb_extinctions_step(eb_extinctions *m, float scale)
{
    if (m->opaque)
        return (float4)(m->rgb_opaque / (float)m->opaque, 1.0f);
    if (!(m->s_sum > 0.0f))
        return (float4)(0.0f);
    float a = 1.0f - eb_exp2_nonpositive(fmax(-m->s_sum * scale, -126.0f));
    return (float4)(m->rgb / m->s_sum, a);
}

/* Opacity (w) and colour (xyz) of a step of length len at lattice point p
 * (sums s, field values `value`, finest level `level`), the mixture of the
 * volume layers (medium.cl); shaded layers use their field's gradient. */
EB_INLINE float4 eb_medium_step(eb_frame *fr, eb_basis_sums *s, float3 p, int level,
                                const float *value, float len, float3 dir_world, const int shade)
{
    eb_look look = fr->look;
    if (look.n_layers == 1) {
        int4 layer = look.layer0;
        float4 c = eb_layer_lookup(look, layer, look.table0, value[layer.x]);
        if (!(c.w > 0.0f))
            return (float4)(0.0f);
        float a = eb_opacity_correct(c.w, len, fr->P->inv_unit_distance);
        float3 rgb = c.xyz;
        if (shade)
            rgb *= eb_headlight(eb_field_gradient(fr, s, p, level, layer.x), dir_world);
        return (float4)(rgb, a);
    }
    eb_extinctions mix = eb_extinctions_none();
    for (int i = 0; i < look.n_layers; ++i) {
        int4 layer = look.layers[i];
        float4 c = eb_layer_lookup(look, layer, look.table_at[i], value[layer.x]);
        if (!(c.w > 0.0f))
            continue;
        float3 ci = c.xyz;
        if (shade)
            ci *= eb_headlight(eb_field_gradient(fr, s, p, level, layer.x), dir_world);
        eb_extinctions_add(&mix, c.w, ci);
    }
    return eb_extinctions_step(&mix, len * fr->P->inv_unit_distance);
}
