/* The shadow integrator's light (docs/design-rendering.md, "Lights and shadows"),
 * built with -DEB_SHADOW: one directional light toward light_dir.xyz (world,
 * unit) of colour x intensity light_rgb.xyz, and the ambient term light_rgb.w;
 * a surface hit's shadow ray starts light_dir.w (world) off the surface along its
 * normal (picture/light.py, SHADOW_BIAS_CELLS). What
 * reaches a point is ambient + T light_rgb.xyz, T the transmittance from the
 * point toward the light: the volume layers' extinction and every iso-surface,
 * slice and mesh crossed, inside the clip region, integrated as a primary ray
 * is (occlusion.cl's eb_visibility: the same regions, steps and opacity
 * correction), so a dense shell shades what lies behind it; by default the
 * volume layers' part of T comes from a cache made once per light
 * (light_volume.cl). A volume sample
 * scatters it isotropically (its colour times that light: the albedo is the
 * transfer function's colour); a surface hit takes it through Lambert's cosine
 * (and the Blinn-Phong specular term toward the light). */
#pragma once
#include "common.h"
#include "occlusion.cl"
#include "light_volume.cl"

#ifdef EB_SHADOW
/* Transmittance toward the light from world point p: traced, or with the
 * volume layers' part cached (light_dims.w, --shadow-rays cached:
 * light_volume.cl) and the surfaces' traced. */
EB_INLINE float eb_light_transmittance(eb_frame *fr, float3 p, float rho)
{
    int cached = fr->P->light_dims.w;
#ifndef EB_SURFACES
    if (cached)  /* no iso-surface, slice or mesh to cross: the volume's part is all */
        return eb_light_cached(fr, p);
#endif
    float t = eb_visibility(fr, p, fr->P->light_dir.xyz, 0.0f, EB_INF, rho, !cached);
    return cached ? t * eb_light_cached(fr, p) : t;
}

/* The light that reaches a volume sample at world point p. */
EB_INLINE float3 eb_light(eb_frame *fr, float3 p, float rho)
{
    return (float3)(fr->P->light_rgb.w) + eb_light_transmittance(fr, p, rho) * fr->P->light_rgb.xyz;
}
#endif
