/* The dataset's buffers (EB_DATASET_ARGS) as the structures the kernels walk.
 *
 * The host groups the dataset's arrays by element type
 * (exabricks.engine.device_data.DeviceDataset) and says where each starts in the
 * frame's eb_params (exabricks.device.kernel_abi.PARAMS, the "*_at" members):
 *   geometry  float:  BVH node and region boxes, (n, 3) lower and upper corners;
 *   links     int:    BVH (first, count) links, its leaf-order region ids, and
 *                     its nodes' parents and child orders (walk_links);
 *   flags     uchar:  node and region visibility bits (per frame), region finest level;
 *   brick_grid float4: per brick its box (lower corner, 1 / width), then per
 *                     brick its dims (N.x, N.y, N.z, level) as int4;
 *   tree      4-byte words: the cell-location tree's corners, links and brick
 *                     ids (-DEB_CELL_LOCATION only; a dummy otherwise);
 * the brick lists, brick values and the per-brick vertex and mip values each
 * have a buffer of their own. */
#pragma once
#include "common.h"
#include "traversal.cl"
#include "reconstruction.cl"
#ifdef EB_CELL_LOCATION
#include "cell_location.cl"
#endif

#define EB_DATASET_ARGS                                                          \
    __global const float *geometry, __global const int *links,                  \
    __global const uchar *flags, __global const long *brick_start,               \
    __global const int *brick_ids, __global const float4 *brick_grid,            \
    __global const long *brick_offset, __global const float *brick_values,       \
    __global const long *vertex_offset, __global const float *vertex_values,     \
    __global const long *mip_offset, __global const float *mip_values,           \
    __global const float *tree
#define EB_DATASET geometry, links, flags, brick_start, brick_ids, brick_grid,    \
    brick_offset, brick_values, vertex_offset, vertex_values, mip_offset,        \
    mip_values, tree

EB_INLINE eb_bvh eb_bvh_of(eb_params_ref P, EB_DATASET_ARGS)
{
    eb_bvh bvh = {geometry + P->node_lower_at, geometry + P->node_upper_at,
                  (__global const int2 *)(links + P->node_link_at), links + P->node_region_at,
                  flags + P->node_visible_at, links + P->node_parent_at, P->n_nodes, P->n_regions};
    return bvh;
}

EB_INLINE eb_regions eb_regions_of(eb_params_ref P, EB_DATASET_ARGS)
{
    eb_regions regions = {geometry + P->region_lower_at, geometry + P->region_upper_at,
                          brick_start, brick_ids,
                          (__global const char *)(flags + P->region_level_at),
                          flags + P->region_visible_at};
    return regions;
}

EB_INLINE eb_bricks eb_bricks_of(eb_params_ref P, EB_DATASET_ARGS)
{
    eb_bricks bricks = {brick_grid, (__global const int4 *)(brick_grid + P->n_bricks),
                        brick_offset, brick_values, P->field_stride,
#ifndef EB_RECONSTRUCTION
                        P->reconstruction,
#endif
                        vertex_offset, vertex_values, P->vertex_stride,
                        mip_offset, mip_values, P->mip_stride};
    return bricks;
}

#ifdef EB_CELL_LOCATION
EB_INLINE eb_brick_tree eb_tree_of(eb_params_ref P, EB_DATASET_ARGS)
{
    eb_brick_tree t = {tree + P->tree_lower_at, tree + P->tree_upper_at,
                       (__global const int2 *)(tree + P->tree_link_at),
                       (__global const int *)(tree + P->tree_brick_at), P->n_tree_nodes};
    return t;
}
#endif
