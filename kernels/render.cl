/* Kernel entry points: `eb_render` (one frame sample per pixel) and `eb_probe`
 * (field values at points). Everything else lives in one file per concept. */
#include "common.h"
#include "sampler.cl"
#include "camera.cl"
#include "integrator.cl"

#define EB_BVH_ARGS                                                             \
    __global const float *bvh_lower, __global const float *bvh_upper,           \
    __global const int2 *bvh_link, __global const int *bvh_region_index,        \
    __global const uchar *bvh_visible, int bvh_n_nodes, int bvh_n_regions
#define EB_REGION_ARGS                                                          \
    __global const float *region_lower, __global const float *region_upper,     \
    __global const long *region_brick_start, __global const int *region_brick_ids, \
    __global const char *region_finest_level, __global const uchar *region_visible
#define EB_BRICK_ARGS                                                           \
    __global const float4 *brick_box, __global const int4 *brick_dims,          \
    __global const long *brick_offset, __global const float *brick_values,      \
    long field_stride, __global const long *vertex_offset,                      \
    __global const float *vertex_values, long vertex_stride,                    \
    __global const long *mip_offset, __global const float *mip_values, long mip_stride
#define EB_BVH_STRUCT                                                           \
    {bvh_lower, bvh_upper, bvh_link, bvh_region_index, bvh_visible,            \
     bvh_n_nodes, bvh_n_regions}
#define EB_REGION_STRUCT                                                        \
    {region_lower, region_upper, region_brick_start, region_brick_ids,          \
     region_finest_level, region_visible}
#define EB_BRICK_STRUCT {brick_box, brick_dims, brick_offset, brick_values, field_stride, \
                         vertex_offset, vertex_values, vertex_stride,                \
                         mip_offset, mip_values, mip_stride}

/* The frame's look, surfaces and clipping (exabricks.stages.render.frame_args). */
#define EB_FRAME_ARGS                                                           \
    __global const float *tf_xs, __global const float4 *tf_rgba,                \
    __global const int *tf_buckets, __global const int4 *layers, int n_layers, __global const float4 *gradient_scale, \
    __global const int4 *iso, __global const float4 *iso_value,                 \
    __global const float4 *iso_color, int n_iso,                                \
    __global const int4 *slice, __global const float4 *slice_point,             \
    __global const float4 *slice_normal, int n_slices,                          \
    float iso_tolerance, float specular, float shininess,                       \
    int clip_box, float4 clip_lower, float4 clip_upper,                         \
    __global const float4 *clip_planes, int n_clip_planes

/* eb_render's extra arguments for a piece of a frame split by space (scene.cl
 * eb_in_piece): its box in lattice space and, where use_front, the premultiplied
 * RGBA of this sample composited so far in front of the piece (one per pixel
 * of the band), which the piece's rays continue from (so that early ray
 * termination carries across pieces; exabricks.stages.streaming). */
#ifdef EB_PIECE
#define EB_PIECE_ARGS , float4 piece_lower, float4 piece_upper,                 \
    __global const float4 *front, int use_front
#else
#define EB_PIECE_ARGS
#endif

/* eb_render's extra arguments for the cell-location variant (integrator.cl):
 * the tree over the brick supports, exabricks.stages.cell_location.BrickTree. */
#ifdef EB_CELL_LOCATION
#define EB_LOCATION_ARGS                                                        \
    , __global const float *tree_lower, __global const float *tree_upper,       \
    __global const int2 *tree_link, __global const int *tree_brick_index,      \
    int tree_n_nodes
#define EB_SAMPLE_BRICKS_STRUCT                                                 \
    {EB_BRICK_STRUCT, {tree_lower, tree_upper, tree_link, tree_brick_index,     \
                       tree_n_nodes}}
#else
#define EB_LOCATION_ARGS
#define EB_SAMPLE_BRICKS_STRUCT EB_BRICK_STRUCT
#endif

/* Sample `sample_index` of `spp` of every pixel in rows row0 .. row0 + rows - 1
 * and columns col0 .. col0 + cols - 1 of a width x height frame (the host
 * renders a frame, or a tile of it, in bands of rows, so that each enqueue
 * ends well within a second and a signal can stop the run), averaged into
 * rgba, which holds that band, cols pixels a row (sample 0 overwrites, so the
 * buffer needs no clearing).
 * Sub-pixel position: the pixel centre for spp == 1, else uniform from the
 * seeded hash. Interleaving offset rho: from the hash with jitter, else 0.5.
 * samples[pixel] and depth[pixel] collect the reconstruction count and the
 * smallest depth over the pixel's samples. */
__kernel void eb_render(int width, int height, int row0, int rows, int col0, int cols,
                        int sample_index, int spp, uint seed, int jitter,
                        float4 cam_origin, float4 cam_forward, float4 cam_du, float4 cam_dv,
                        float4 origin_world, float4 inv_spacing,
                        float step_base, float inv_unit_distance, float max_opacity, int shading,
                        int ordered, int central, int ao_samples, float ao_distance,
                        float lod_scale,
                        EB_BVH_ARGS, EB_REGION_ARGS, EB_BRICK_ARGS EB_LOCATION_ARGS,
                        EB_FRAME_ARGS EB_PIECE_ARGS,
                        __global float4 *rgba, __global float *depth, __global uint *samples,
                        __global uint *level_samples)
{
    int band_col = get_global_id(0), band_row = get_global_id(1);
    int col = col0 + band_col, row = row0 + band_row;
    if (band_col >= cols || band_row >= rows || col >= width || row >= height)
        return;
    /* seeds the hash: bands and tiles change nothing */
    uint pixel = (uint)row * (uint)width + (uint)col;
    uint slot = (uint)band_row * (uint)cols + (uint)band_col;
    eb_frame fr = {
        EB_BVH_STRUCT, EB_REGION_STRUCT, EB_SAMPLE_BRICKS_STRUCT,
        {tf_xs, tf_rgba, tf_buckets, layers, n_layers, layers[0]},
        {iso, iso_value, iso_color, n_iso, slice, slice_point, slice_normal, n_slices,
         iso_tolerance, specular, shininess},
        {clip_box, clip_lower, clip_upper, clip_planes, n_clip_planes},
        step_base, inv_unit_distance, max_opacity, shading, central, ao_samples, ao_distance,
        origin_world, inv_spacing, lod_scale,
#ifdef EB_PIECE
        piece_lower, piece_upper,
#endif
    };

    for (int f = 0; f < EB_N_FIELDS; ++f)
        fr.look.gradient_scale[f] = gradient_scale[f].xyz;

    float jx = 0.5f, jy = 0.5f;
    if (spp > 1) {
        jx = eb_random(pixel, (uint)sample_index, seed, 1u);
        jy = eb_random(pixel, (uint)sample_index, seed, 2u);
    }
    eb_ray ray;
    ray.rho = jitter ? eb_random(pixel, (uint)sample_index, seed, 0u) : 0.5f;
    ray.pixel = pixel;
    ray.sample = (uint)sample_index;
    ray.seed = seed;
    ray.org_world = cam_origin.xyz;
    ray.dir_world = eb_camera_direction(cam_forward.xyz, cam_du.xyz, cam_dv.xyz,
                                        col, row, width, height, jx, jy);
    ray.org = eb_world_to_lattice(cam_origin.xyz, origin_world.xyz, inv_spacing.xyz);
    ray.dir = ray.dir_world * inv_spacing.xyz;
    ray.inv_dir = 1.0f / ray.dir;
    uint n;
    float t_depth;
    float4 c;
    float4 before = (float4)(0.0f);
#ifdef EB_PIECE
    if (use_front)
        before = front[slot];
#endif
    /* Constant shade/ordered arguments let the compiler drop the unused paths. */
    if (ordered)
        c = shading ? eb_integrate(&fr, &ray, 1, 1, before, &n, &t_depth, level_samples)
                    : eb_integrate(&fr, &ray, 0, 1, before, &n, &t_depth, level_samples);
    else
        c = shading ? eb_integrate(&fr, &ray, 1, 0, before, &n, &t_depth, level_samples)
                    : eb_integrate(&fr, &ray, 0, 0, before, &n, &t_depth, level_samples);
    c /= (float)spp;
    if (sample_index == 0) {
        rgba[slot] = c;
        samples[slot] = n;
        depth[slot] = t_depth;
    } else {
        rgba[slot] += c;
        samples[slot] += n;
        depth[slot] = fmin(depth[slot], t_depth);
    }
}

/* The reconstructed fields at n world points (x, y, z packed, float): field f
 * of point i in values[f * n + i]; NaN where no region contains the point or
 * no cell has support there (no containing cell, for nearest and vertex). */
__kernel void eb_probe(int n, __global const float *points_world,
                       float4 origin_world, float4 inv_spacing,
                       EB_BVH_ARGS, EB_REGION_ARGS, EB_BRICK_ARGS,
                       __global float *values)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    eb_bvh bvh = EB_BVH_STRUCT;
    eb_regions regions = EB_REGION_STRUCT;
    eb_bricks bricks = EB_BRICK_STRUCT;
    float3 p = eb_world_to_lattice(vload3(i, points_world), origin_world.xyz, inv_spacing.xyz);
    int r = eb_find_region(bvh, regions, p);
    eb_basis_sums s = eb_basis_zero();
    if (r >= 0)
        s = eb_reconstruct(bricks, regions.brick_ids, regions.brick_start[r],
                           regions.brick_start[r + 1], p, 0);
    for (int f = 0; f < EB_N_FIELDS; ++f)
        values[f * n + i] = s.weight > 0.0f ? eb_basis_value(s, f) : NAN;
}
