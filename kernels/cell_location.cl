/* Per-sample cell location (paper §6.4.2, Table 3): the basis reconstruction
 * of reconstruction.cl, with the bricks found by descending a tree over the
 * brick supports from the root for every sample (as Wald et al. 2017 locate
 * cells) instead of read from the Active Brick Region's list. Built only with
 * -DEB_CELL_LOCATION (exabricks.stages.render, reconstruction="cell-location"),
 * to measure what the regions save; the default program does not include it. */
#pragma once
#include "common.h"
#include "reconstruction.cl"
#include "traversal.cl"

/* EB_LOCATE_MAX (exabricks.device.kernel_abi): bricks a sample sorts before summing;
 * any beyond are summed unsorted (still correct, only no longer in the
 * regions' order). */

/* exabricks.engine.cell_location.BrickTree on the device. */
typedef struct {
    __global const float *lower;    /* node boxes: union of the supports below, lattice units */
    __global const float *upper;    /* (n, 3) corners: traversal.cl, EB_CORNER */
    __global const int2 *link;      /* (first, count); count 0: inner node */
    __global const int *brick_index;
    int n_nodes;
} eb_brick_tree;

/* The bricks and the tree over their supports: what a cell-location sample reads. */
typedef struct {
    eb_bricks bricks;
    eb_brick_tree tree;
} eb_located_bricks;

/* Sums of eq. 1-2 at lattice point p over the bricks of the leaves whose boxes
 * contain p, found by the descent of traversal.cl (eb_add_brick tests each
 * brick's support itself; one touched only on its boundary adds zero weight).
 * The bricks are summed in ascending id, the order of a region's list, so
 * both reconstructions round alike and give the same frame bit for bit: in a
 * locally constant field the normalised gradient is rounding noise, which any
 * other order would change. */
EB_INLINE eb_basis_sums eb_locate_reconstruct(eb_located_bricks located, float3 p,
                                              const int want_gradient)
{
    eb_brick_tree tree = located.tree;
    eb_basis_sums s = eb_basis_zero();
    int found[EB_LOCATE_MAX];
    int n_found = 0;
    eb_descent d;
    eb_descent_start(&d, tree.lower, tree.upper, p);
    int leaf;
    while ((leaf = eb_descent_next(&d, tree.lower, tree.upper, tree.link, p, tree.n_nodes)) >= 0) {
        int2 link = tree.link[leaf];
        for (int i = link.x; i < link.x + link.y; ++i) {
            int b = tree.brick_index[i];
            if (n_found == EB_LOCATE_MAX) {
                eb_add_brick(located.bricks, b, p, &s, want_gradient);
                continue;
            }
            int k = n_found++;
            for (; k > 0 && found[k - 1] > b; --k)
                found[k] = found[k - 1];
            found[k] = b;
        }
    }
    for (int k = 0; k < n_found; ++k)
        eb_add_brick(located.bricks, found[k], p, &s, want_gradient);
    return s;
}
