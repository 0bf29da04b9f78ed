/* The shadow integrator's cached transmittance toward the light
 * (docs/design-rendering.md, "Lights and shadows"; exabricks.engine.light_volume):
 * a light-space volume of nodes, P->light_dims = (nu, nv, nw, cached) of them,
 * over the data's box as the light sees it. Node (i, j, k) lies at
 * light_origin + i du u + j dv v + k dw w, where u and v are unit axes across
 * the light (light_u, light_v: the axis, and in w 1 / du and 1 / dv) and w =
 * -light_dir, away from the light (1 / dw in light_origin.w). Each column
 * (i, j) is one ray marched from the light's side of the box as a shadow ray
 * is (occlusion.cl's eb_visibility: the same regions, steps, opacity
 * correction and clip interval), and holds the optical depth of the volume
 * layers (-log2 of their transmittance) from the box's edge down to each of
 * its nodes, k fastest, added to what the buffer holds: a domain of a partition
 * (frame.cl, eb_in_domain) adds the optical depth of its own samples, and the
 * domains' sum is the whole's. A sample interpolates the optical depth along the four
 * columns about it (linear in depth through a uniform medium, where the
 * transmittance is not), then their transmittances across the light; iso-surfaces, slices and
 * meshes, whose shadows are sharp, keep their exact shadow rays (light.cl). */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "medium.cl"
#include "occlusion.cl"

#ifdef EB_SHADOW
/* Column (i, j): the optical depth of the volume layers (-log2 of their
 * transmittance) at its nodes, of the samples in the frame's domain, added to out[k]. */
EB_INLINE void eb_light_column(eb_frame *fr, int i, int j, __global float *out)
{
    eb_params_ref P = fr->P;
    int nw = P->light_dims.z;
    float dw = 1.0f / P->light_origin.w;
    float3 dir_world = -P->light_dir.xyz;
    float3 org_world = P->light_origin.xyz + ((float)i / P->light_u.w) * P->light_u.xyz
                       + ((float)j / P->light_v.w) * P->light_v.xyz;
    float2 keep = eb_clip_interval(fr->clip, org_world, dir_world, 0.0f);
    float t_max = fmin(keep.y, dw * (float)(nw - 1));
    const float depth_max = -log2(EB_AO_CUTOFF);  /* where a shadow ray stops */
    float depth = 0.0f;
    int k = 0;
    if (t_max > keep.x && fr->look.n_layers > 0) {
        float3 org = eb_world_to_lattice(org_world, P->origin_world.xyz, P->inv_spacing.xyz);
        float3 dir = dir_world * P->inv_spacing.xyz;
        float3 inv_dir = 1.0f / dir;
        eb_walk w;
        eb_walk_start(&w, fr->bvh, org, inv_dir, keep.x, t_max, EB_SEEN_VOLUME);
        float t_in, t_out;
        int r;
        while (depth < depth_max && (r = eb_walk_next(&w, fr->bvh, fr->regions, org, inv_dir,
                                                        &t_in, &t_out, EB_SEEN_VOLUME)) >= 0) {
            float dt = ldexp(P->step_base, (int)fr->regions.finest_level[r]);
            eb_intervals it = eb_intervals_start(t_in, t_out, dt, 0.5f);
            float tm, len;
            while (depth < depth_max && eb_intervals_next(&it, &tm, &len)) {
                float a = 0.0f;
                eb_basis_sums s = eb_sample_region(fr, r, org + tm * dir, 0);
                if (s.weight > 0.0f && eb_in_domain(fr, org + tm * dir)) {
                    float value[EB_N_FIELDS];
                    eb_fields(s, value);
                    a = eb_medium_step(fr, &s, org + tm * dir, 0, value, len, dir_world, 0).w;
                }
                /* the sample's sub-interval [tm - len / 2, tm + len / 2] dims the
                 * nodes in it by the part of it before them */
                float step = a < 1.0f ? -log2(1.0f - a) : depth_max;
                for (; k < nw && (float)k * dw <= tm + 0.5f * len; ++k)
                    out[k] += depth + step * clamp(((float)k * dw - (tm - 0.5f * len)) / len, 0.0f, 1.0f);
                depth += step;
            }
        }
    }
    for (; k < nw; ++k)
        out[k] += depth;
}

/* The cached transmittance of the volume layers toward the light at world point
 * p: 1 where the light reaches p outside the data's box. */
EB_INLINE float eb_light_cached(eb_frame *fr, float3 p)
{
    eb_params_ref P = fr->P;
    int4 n = P->light_dims;
    float3 q = p - P->light_origin.xyz;
    float x = dot(q, P->light_u.xyz) * P->light_u.w;
    float y = dot(q, P->light_v.xyz) * P->light_v.w;
    float z = -dot(q, P->light_dir.xyz) * P->light_origin.w;
    if (!(x >= 0.0f && y >= 0.0f && z >= 0.0f && x <= (float)(n.x - 1) && y <= (float)(n.y - 1)))
        return 1.0f;
    z = fmin(z, (float)(n.z - 1));
    int i = min((int)x, n.x - 2), j = min((int)y, n.y - 2), k = min((int)z, n.z - 2);
    float fx = x - (float)i, fy = y - (float)j, fz = z - (float)k;
    size_t sx = (size_t)n.z, sy = (size_t)n.x * (size_t)n.z;
    __global const float *c = fr->light + (size_t)j * sy + (size_t)i * sx + (size_t)k;
    float c00 = exp2(-mix(c[0], c[1], fz)), c10 = exp2(-mix(c[sx], c[sx + 1], fz));
    float c01 = exp2(-mix(c[sy], c[sy + 1], fz)), c11 = exp2(-mix(c[sy + sx], c[sy + sx + 1], fz));
    return mix(mix(c00, c10, fx), mix(c01, c11, fx), fy);
}

#ifdef EB_PACKET
#include "packet.cl"
/* eb_light_cached at EB_PACKET world points (px, py, pz), one a lane: the same
 * interpolation, its arithmetic and exp2 across the lanes at once. */
EB_INLINE eb_vf eb_light_cached_packet(eb_frame *fr, eb_vf px, eb_vf py, eb_vf pz)
{
    eb_params_ref P = fr->P;
    int4 n = P->light_dims;
    eb_vf qx = px - P->light_origin.x, qy = py - P->light_origin.y, qz = pz - P->light_origin.z;
    eb_vf x = (qx * P->light_u.x + qy * P->light_u.y + qz * P->light_u.z) * P->light_u.w;
    eb_vf y = (qx * P->light_v.x + qy * P->light_v.y + qz * P->light_v.z) * P->light_v.w;
    eb_vf z = -(qx * P->light_dir.x + qy * P->light_dir.y + qz * P->light_dir.z) * P->light_origin.w;
    eb_vi in = (x >= 0.0f) & (y >= 0.0f) & (z >= 0.0f) & (x <= (float)(n.x - 1))
               & (y <= (float)(n.y - 1));
    x = clamp(x, 0.0f, (float)(n.x - 1));  /* lanes outside read node 0: set to 1 below */
    y = clamp(y, 0.0f, (float)(n.y - 1));
    z = clamp(z, 0.0f, (float)(n.z - 1));
    eb_vi i = min(eb_convert_vi(x), n.x - 2), j = min(eb_convert_vi(y), n.y - 2);
    eb_vi k = min(eb_convert_vi(z), n.z - 2);
    eb_vf fx = x - eb_convert_vf(i), fy = y - eb_convert_vf(j), fz = z - eb_convert_vf(k);
    int sx = n.z, sy = n.x * n.z;  /* at most MAX_NODES = 2^24: an int */
    eb_vi c = j * sy + i * sx + k;
    __global const float *v = fr->light;
    eb_vf c00 = exp2(-mix(EB_GATHER(v, c), EB_GATHER(v, c + 1), fz));
    eb_vf c10 = exp2(-mix(EB_GATHER(v, c + sx), EB_GATHER(v, c + sx + 1), fz));
    eb_vf c01 = exp2(-mix(EB_GATHER(v, c + sy), EB_GATHER(v, c + sy + 1), fz));
    eb_vf c11 = exp2(-mix(EB_GATHER(v, c + sy + sx), EB_GATHER(v, c + sy + sx + 1), fz));
    return select((eb_vf)(1.0f), mix(mix(c00, c10, fx), mix(c01, c11, fx), fy), in);
}
#endif
#endif
