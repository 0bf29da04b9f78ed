/* Walking the BVH over the Active Brick Regions (paper §3.3, §4).
 *
 * Rays visit the regions they overlap in exact front-to-back order, whatever
 * the builder's node boxes overlap (regions are disjoint, node boxes need not
 * be). Two walks:
 *  - ordered (default): one traversal per ray with a private min-heap of
 *    nodes and regions keyed by entry distance; popping a region means every
 *    node and region still queued starts behind it, so it is the next one.
 *  - re-trace (the paper's scheme, §4): a closest-hit traversal from the root
 *    for every region, starting where the previous region ended. Used when the
 *    heap would overflow, and selectable for comparison.
 * Space skipping (paper §4.1): nodes and regions whose value range maps to zero
 * opacity under the current transfer function carry visible = 0 (computed on
 * the host per frame, so a new transfer function needs no BVH rebuild) and are
 * never entered.
 * Points (probe, cell location): one descent (eb_descent) that yields the
 * leaves whose boxes contain a point.
 * The trees are checked on load (exabricks.schema): children follow their
 * parent, every node has one parent, and the depth fits EB_STACK_SIZE; every
 * loop here is also bounded by the node and region counts. */
#pragma once
#include "common.h"

/* Box i's corner from an (n, 3) float32 array of corners: the boxes of the
 * BVH, the regions and the cell-location tree are read in the layout their
 * files hold them (grouped by exabricks.engine.device_data, dataset.cl). */
#define EB_CORNER(corners, i) vload3((i), (corners))

/* exabricks.schema.Bvh on the device: node boxes, (first, count) links, the
 * leaf-order region ids, and the per-frame visibility flags. */
typedef struct {
    __global const float *lower;
    __global const float *upper;
    __global const int2 *link;         /* (first, count); count 0: inner node */
    __global const int *region_index;
    __global const uchar *visible;
    int n_nodes;                       /* loop bounds: every walk visits each */
    int n_regions;                     /* node and region at most once        */
} eb_bvh;

/* exabricks.schema.Regions on the device. */
typedef struct {
    __global const float *lower;
    __global const float *upper;
    __global const long *brick_start;  /* CSR row pointers into brick_ids */
    __global const int *brick_ids;
    __global const char *finest_level;
    __global const uchar *visible;
} eb_regions;

/* The visible region with the smallest entry distance among those the ray
 * overlaps over a non-empty interval after t_cur (and before t_max); -1 if none.
 * On success [*t_in, *t_out] is that overlap, clipped to [t_cur, t_max], with
 * *t_out > *t_in >= t_cur: the caller's next search starts at *t_out, so the
 * walk always advances and visits every region at most once. */
inline int eb_next_region(eb_bvh bvh, eb_regions regions, float3 org, float3 inv_dir,
                          float t_cur, float t_max, float *t_in, float *t_out)
{
    int stack[EB_STACK_SIZE];
    float stack_t[EB_STACK_SIZE];
    int sp = 0;
    int best = -1;
    float best_in = t_max, best_out = t_max;

    if (!bvh.visible[0])
        return -1;
    float2 root = eb_box_interval(EB_CORNER(bvh.lower, 0), EB_CORNER(bvh.upper, 0), org, inv_dir);
    if (fmin(root.y, t_max) <= fmax(root.x, t_cur))
        return -1;
    stack[sp] = 0;
    stack_t[sp++] = fmax(root.x, t_cur);

    for (int steps = 0; sp > 0 && steps < bvh.n_nodes; ++steps) {
        --sp;
        if (stack_t[sp] >= best_in)
            continue;  /* a nearer region was found since this node was pushed */
        int node = stack[sp];
        int2 link = bvh.link[node];
        if (link.y > 0) {
            for (int i = link.x; i < link.x + link.y; ++i) {
                int r = bvh.region_index[i];
                if (!regions.visible[r])
                    continue;
                float2 iv = eb_box_interval(EB_CORNER(regions.lower, r),
                                            EB_CORNER(regions.upper, r), org, inv_dir);
                float t0 = fmax(iv.x, t_cur), t1 = fmin(iv.y, t_max);
                if (t1 > t0 && t0 < best_in) {
                    best = r;
                    best_in = t0;
                    best_out = t1;
                }
            }
            continue;
        }
        int c = link.x;
        float t_near[2];
        int hit[2];
        for (int k = 0; k < 2; ++k) {
            float2 iv = eb_box_interval(EB_CORNER(bvh.lower, c + k), EB_CORNER(bvh.upper, c + k),
                                        org, inv_dir);
            t_near[k] = fmax(iv.x, t_cur);
            hit[k] = bvh.visible[c + k] && fmin(iv.y, t_max) > t_near[k] && t_near[k] < best_in;
        }
        /* Push the far child first so the near one is popped first. */
        int first = t_near[1] < t_near[0] ? 1 : 0;
        int second = 1 - first;
        if (hit[second] && sp < EB_STACK_SIZE) {
            stack[sp] = c + second;
            stack_t[sp++] = t_near[second];
        }
        if (hit[first] && sp < EB_STACK_SIZE) {
            stack[sp] = c + first;
            stack_t[sp++] = t_near[first];
        }
    }
    *t_in = best_in;
    *t_out = best_out;
    return best;
}

/* EB_QUEUE_SIZE (exabricks.device.kernel_abi.TUNABLES): the capacity of the ordered
 * walk's heap. The queued nodes and regions lie ahead of the ray front on
 * disjoint subtrees, a few tens for any BVH seen so far. A build option
 * -DEB_QUEUE_SIZE=n overrides it (tests force overflow with 2). */

/* A binary min-heap of (key, item) pairs in private arrays. */
typedef struct {
    float key[EB_QUEUE_SIZE];
    int item[EB_QUEUE_SIZE];
    int size;
} eb_queue;

EB_INLINE void eb_queue_push(eb_queue *q, float key, int item)
{
    int i = q->size++;
    while (i > 0) {
        int parent = (i - 1) >> 1;
        if (q->key[parent] <= key)
            break;
        q->key[i] = q->key[parent];
        q->item[i] = q->item[parent];
        i = parent;
    }
    q->key[i] = key;
    q->item[i] = item;
}

EB_INLINE int eb_queue_pop(eb_queue *q)
{
    int top = q->item[0];
    int n = --q->size;
    float key = q->key[n];
    int item = q->item[n];
    int i = 0;
    for (;;) {
        int c = 2 * i + 1;
        if (c >= n)
            break;
        if (c + 1 < n && q->key[c + 1] < q->key[c])
            ++c;
        if (key <= q->key[c])
            break;
        q->key[i] = q->key[c];
        q->item[i] = q->item[c];
        i = c;
    }
    q->key[i] = key;
    q->item[i] = item;
    return top;
}

/* Queue items: a node as its index, a region r as ~r (negative). */
EB_INLINE void eb_queue_start(eb_queue *q, eb_bvh bvh, float3 org, float3 inv_dir,
                              float t_min, float t_max)
{
    q->size = 0;
    if (!bvh.visible[0])
        return;
    float2 iv = eb_box_interval(EB_CORNER(bvh.lower, 0), EB_CORNER(bvh.upper, 0), org, inv_dir);
    float t0 = fmax(iv.x, t_min);
    if (fmin(iv.y, t_max) > t0)
        eb_queue_push(q, t0, 0);
}

/* Expand node `node` into the queue: its visible children, or the visible
 * regions of a leaf, that the ray overlaps over a non-empty interval after
 * t_cur (and before t_max). Returns 0 if the queue overflowed (the caller
 * must fall back). */
EB_INLINE int eb_queue_expand(eb_queue *q, eb_bvh bvh, eb_regions regions, int node,
                              float3 org, float3 inv_dir, float t_cur, float t_max)
{
    int2 link = bvh.link[node];
    if (link.y > 0) {
        for (int i = link.x; i < link.x + link.y; ++i) {
            int r = bvh.region_index[i];
            if (!regions.visible[r])
                continue;
            float2 iv = eb_box_interval(EB_CORNER(regions.lower, r), EB_CORNER(regions.upper, r),
                                        org, inv_dir);
            float t0 = fmax(iv.x, t_cur);
            if (fmin(iv.y, t_max) > t0) {
                if (q->size == EB_QUEUE_SIZE)
                    return 0;
                eb_queue_push(q, t0, ~r);
            }
        }
        return 1;
    }
    for (int c = link.x; c < link.x + 2; ++c) {
        if (!bvh.visible[c])
            continue;
        float2 iv = eb_box_interval(EB_CORNER(bvh.lower, c), EB_CORNER(bvh.upper, c), org, inv_dir);
        float t0 = fmax(iv.x, t_cur);
        if (fmin(iv.y, t_max) > t0) {
            if (q->size == EB_QUEUE_SIZE)
                return 0;
            eb_queue_push(q, t0, c);
        }
    }
    return 1;
}

/* The regions along a ray segment [t_min, t_max], front to back: the ordered
 * walk, finishing with the re-trace walk from where it stopped if its heap
 * fills up (or throughout with ordered == 0). Every region is returned at most
 * once, with its overlap [*t_in, *t_out] (t_in >= the previous t_out). */
typedef struct {
    eb_queue q;
    float t_cur, t_max;
    int retrace;
    int pops, visits;  /* loop bounds: each node and region is queued at most once */
} eb_walk;

EB_INLINE void eb_walk_start(eb_walk *w, eb_bvh bvh, float3 org, float3 inv_dir,
                             float t_min, float t_max, const int ordered)
{
    w->t_cur = t_min;
    w->t_max = t_max;
    w->retrace = !ordered;
    w->pops = bvh.n_nodes + bvh.n_regions;
    w->visits = bvh.n_regions;
    w->q.size = 0;
    if (ordered)
        eb_queue_start(&w->q, bvh, org, inv_dir, t_min, t_max);
}

EB_PROFILED int eb_walk_next(eb_walk *w, eb_bvh bvh, eb_regions regions, float3 org,
                           float3 inv_dir, float *t_in, float *t_out)
{
    if (!w->retrace) {
        while (w->q.size > 0 && w->pops-- > 0) {
            int item = eb_queue_pop(&w->q);
            if (item >= 0) {
                if (!eb_queue_expand(&w->q, bvh, regions, item, org, inv_dir, w->t_cur, w->t_max)) {
                    w->retrace = 1;  /* heap full: go on with the re-trace walk from t_cur */
                    break;
                }
                continue;
            }
            int r = ~item;
            float2 iv = eb_box_interval(EB_CORNER(regions.lower, r), EB_CORNER(regions.upper, r),
                                        org, inv_dir);
            float a = fmax(iv.x, w->t_cur), b = fmin(iv.y, w->t_max);
            if (!(b > a))
                continue;
            *t_in = a;
            *t_out = b;
            w->t_cur = b;
            return r;
        }
        if (!w->retrace)
            return -1;
    }
    if (w->visits-- <= 0)
        return -1;
    int r = eb_next_region(bvh, regions, org, inv_dir, w->t_cur, w->t_max, t_in, t_out);
    if (r >= 0)
        w->t_cur = *t_out;
    return r;
}

/* A depth-first descent of a flat binary tree (node boxes lower/upper,
 * (first, count) links, count 0 for inner nodes) to the leaves whose boxes
 * contain point p, in tree order (left child first). Shared by eb_find_region
 * and the cell-location variant (cell_location.cl). */
typedef struct {
    int stack[EB_STACK_SIZE];
    int sp;
    int steps;
} eb_descent;

EB_INLINE void eb_descent_start(eb_descent *d, __global const float *lower,
                                __global const float *upper, float3 p)
{
    d->sp = 0;
    d->steps = 0;
    if (eb_point_in_box(p, EB_CORNER(lower, 0), EB_CORNER(upper, 0)))
        d->stack[d->sp++] = 0;
}

/* The next leaf containing p, or -1. n_nodes bounds the loop. */
EB_INLINE int eb_descent_next(eb_descent *d, __global const float *lower,
                              __global const float *upper, __global const int2 *link,
                              float3 p, int n_nodes)
{
    while (d->sp > 0 && d->steps++ < n_nodes) {
        int node = d->stack[--d->sp];
        int2 l = link[node];
        if (l.y > 0)
            return node;
        /* Right child first on the stack, so the left one is visited first. */
        for (int c = l.x + 1; c >= l.x; --c)
            if (eb_point_in_box(p, EB_CORNER(lower, c), EB_CORNER(upper, c))
                && d->sp < EB_STACK_SIZE)
                d->stack[d->sp++] = c;
    }
    return -1;
}

/* The first region (in BVH order) whose box contains lattice point p; -1 if none.
 * Regions are disjoint, and a point on a shared face gets the same value from
 * either side (each lists every brick with support there). Visibility is ignored. */
inline int eb_find_region(eb_bvh bvh, eb_regions regions, float3 p)
{
    eb_descent d;
    eb_descent_start(&d, bvh.lower, bvh.upper, p);
    int leaf;
    while ((leaf = eb_descent_next(&d, bvh.lower, bvh.upper, bvh.link, p, bvh.n_nodes)) >= 0) {
        int2 link = bvh.link[leaf];
        for (int i = link.x; i < link.x + link.y; ++i) {
            int r = bvh.region_index[i];
            if (eb_point_in_box(p, EB_CORNER(regions.lower, r), EB_CORNER(regions.upper, r)))
                return r;
        }
    }
    return -1;
}
