/* Triangle meshes (exabricks.mesh.MeshSet; docs/design-rendering.md, "Meshes"): the
 * triangles of a frame's meshes under one BVH in world units, walked once per
 * ray for the nearest EB_MAX_MESH_HITS hits inside the ray's interval (the
 * surfaces of surfaces.cl composite them in distance order with the volume),
 * and once per ambient-occlusion ray for the transmittance of every hit.
 *
 * Ray-triangle test: watertight (Woop, Benthin and Wald, JCGT 2013): the
 * triangle is sheared into the ray's frame, where the edge functions U, V, W
 * decide the hit; a zero counts as inside for both triangles of an edge, so a
 * ray through an edge or a vertex of a closed mesh hits it and never slips
 * through. Distances are world distances along dir_world (unit length). */
#pragma once
#include "common.h"

/* The meshes of a frame (exabricks.mesh.MeshSet and frame_arrays). */
typedef struct {
    __global const float4 *tri;    /* 3 per triangle; tri[3i].w: its mesh */
    __global const uint *normal;   /* 3 per triangle: its corners' shading normals (octahedron) */
    __global const float4 *node;   /* 2 per node: lower and upper corner, their w the
                                      bits of (first, count): inner nodes count 0 */
    __global const float4 *color;  /* per mesh: r, g, b, opacity */
    __global const int4 *info;     /* per mesh: colour field or -1, first knot, knot count */
    int n_meshes;
} eb_meshes;

/* A ray in the shear frame of the watertight test: perm = (kx, ky, kz, 3) picks
 * a vector's coordinates in that frame (kz: the ray's largest axis). */
typedef struct {
    float3 org, inv_dir;
    float4 org4;
    uint4 perm;
    float sx, sy, sz;
} eb_mesh_ray;

EB_INLINE float eb_axis(float3 v, int k)
{
    return k == 0 ? v.x : (k == 1 ? v.y : v.z);
}

EB_INLINE eb_mesh_ray eb_mesh_ray_of(float3 org, float3 dir)
{
    eb_mesh_ray r;
    r.org = org;
    r.org4 = (float4)(org, 0.0f);
    r.inv_dir = 1.0f / dir;
    float3 a = fabs(dir);
    int kz = a.x >= a.y ? (a.x >= a.z ? 0 : 2) : (a.y >= a.z ? 1 : 2);
    int kx = kz == 2 ? 0 : kz + 1;
    int ky = kx == 2 ? 0 : kx + 1;
    float dz = eb_axis(dir, kz);
    if (dz < 0.0f) {  /* keep the winding */
        int k = kx;
        kx = ky;
        ky = k;
    }
    r.perm = (uint4)(kx, ky, kz, 3);
    r.sx = eb_axis(dir, kx) / dz;
    r.sy = eb_axis(dir, ky) / dz;
    r.sz = 1.0f / dz;
    return r;
}

/* Distance to triangle i if the ray hits it inside (t0, t1], else +inf. */
EB_INLINE float eb_triangle_hit(eb_meshes *m, int i, eb_mesh_ray *r, float t0, float t1)
{
    /* No fused multiply-adds here: an edge's function must come out as exactly
     * the negative in the triangle on its other side (watertightness). */
#pragma OPENCL FP_CONTRACT OFF
    /* the vertices relative to the origin, in the ray's axis order (one permute each) */
    float4 a = shuffle(m->tri[3 * i] - r->org4, r->perm);
    float4 b = shuffle(m->tri[3 * i + 1] - r->org4, r->perm);
    float4 c = shuffle(m->tri[3 * i + 2] - r->org4, r->perm);
    float ax = a.x - r->sx * a.z, ay = a.y - r->sy * a.z;
    float bx = b.x - r->sx * b.z, by = b.y - r->sy * b.z;
    float cx = c.x - r->sx * c.z, cy = c.y - r->sy * c.z;
    float u = cx * by - cy * bx;
    float v = ax * cy - ay * cx;
    float w = bx * ay - by * ax;
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f))
        return EB_INF;
    float det = u + v + w;
    if (det == 0.0f)
        return EB_INF;
    float t = (u * a.z + v * b.z + w * c.z) * r->sz / det;
    return t > t0 && t <= t1 ? t : EB_INF;
}

/* The unit geometric normal of triangle i (world; either side). */
EB_INLINE float3 eb_triangle_normal(eb_meshes *m, int i)
{
    float3 a = m->tri[3 * i].xyz;
    return normalize(cross(m->tri[3 * i + 1].xyz - a, m->tri[3 * i + 2].xyz - a));
}

/* A unit normal from its octahedron code (exabricks.mesh.encode_normals). */
EB_INLINE float3 eb_decode_normal(uint code)
{
    float u = (float)(code & 0xFFFFu) * (2.0f / 65535.0f) - 1.0f;
    float v = (float)(code >> 16) * (2.0f / 65535.0f) - 1.0f;
    float z = 1.0f - fabs(u) - fabs(v);
    float t = fmax(-z, 0.0f);
    return normalize((float3)(u - copysign(t, u), v - copysign(t, v), z));
}

/* The smooth-shading normal of triangle i at world point x on it: its corners'
 * normals (exabricks.mesh.corner_normals) weighted by x's barycentric
 * coordinates (clamped to the triangle); not normalised. */
EB_INLINE float3 eb_triangle_shading_normal(eb_meshes *m, int i, float3 x)
{
    float3 a = m->tri[3 * i].xyz;
    float3 e1 = m->tri[3 * i + 1].xyz - a, e2 = m->tri[3 * i + 2].xyz - a, d = x - a;
    float d00 = dot(e1, e1), d01 = dot(e1, e2), d11 = dot(e2, e2);
    float d20 = dot(d, e1), d21 = dot(d, e2);
    float den = d00 * d11 - d01 * d01;
    float b1 = den > 0.0f ? clamp((d11 * d20 - d01 * d21) / den, 0.0f, 1.0f) : 0.0f;
    float b2 = den > 0.0f ? clamp((d00 * d21 - d01 * d20) / den, 0.0f, 1.0f - b1) : 0.0f;
    __global const uint *c = m->normal + 3 * i;
    return (1.0f - b1 - b2) * eb_decode_normal(c[0]) + b1 * eb_decode_normal(c[1])
           + b2 * eb_decode_normal(c[2]);
}

EB_INLINE int eb_triangle_mesh(eb_meshes *m, int i)
{
    return (int)m->tri[3 * i].w;
}

/* The BVH walk: calls HIT(i, t) for every triangle i the ray hits inside
 * (t0, *t1], nearest subtrees first; HIT may lower *t1 to prune. */
#define EB_MESH_WALK(m, r, t0, t1, HIT)                                                   \
    do {                                                                                  \
        int stack_[EB_STACK_SIZE];                                                        \
        int top_ = 0, node_ = 0;                                                          \
        for (;;) {                                                                        \
            int2 l_ = (int2)(as_int((m)->node[2 * node_].w), as_int((m)->node[2 * node_ + 1].w)); \
            if (l_.y > 0) {                                                               \
                for (int i_ = l_.x; i_ < l_.x + l_.y; ++i_) {                             \
                    float th_ = eb_triangle_hit((m), i_, (r), (t0), *(t1));               \
                    if (th_ < EB_INF) {                                                   \
                        HIT(i_, th_);                                                     \
                    }                                                                     \
                }                                                                         \
            } else {                                                                      \
                int c_ = l_.x;                                                            \
                float2 n0_ = eb_box_interval((m)->node[2 * c_].xyz, (m)->node[2 * c_ + 1].xyz, \
                                             (r)->org, (r)->inv_dir);                     \
                float2 n1_ = eb_box_interval((m)->node[2 * c_ + 2].xyz,                   \
                                             (m)->node[2 * c_ + 3].xyz, (r)->org, (r)->inv_dir); \
                int h0_ = n0_.x <= n0_.y && n0_.y > (t0) && n0_.x <= *(t1);               \
                int h1_ = n1_.x <= n1_.y && n1_.y > (t0) && n1_.x <= *(t1);               \
                if (h0_ && h1_) {                                                         \
                    int near_ = n0_.x <= n1_.x ? c_ : c_ + 1;                             \
                    if (top_ < EB_STACK_SIZE)                                             \
                        stack_[top_++] = near_ == c_ ? c_ + 1 : c_;                       \
                    node_ = near_;                                                        \
                    continue;                                                             \
                }                                                                         \
                if (h0_ || h1_) {                                                         \
                    node_ = h0_ ? c_ : c_ + 1;                                            \
                    continue;                                                             \
                }                                                                         \
            }                                                                             \
            if (top_ == 0)                                                                \
                break;                                                                    \
            node_ = stack_[--top_];                                                       \
        }                                                                                 \
    } while (0)
