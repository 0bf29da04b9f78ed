/* Walking the BVH over the Active Brick Regions (paper §3.3, §4).
 *
 * Rays visit the regions they overlap in exact front-to-back order, whatever
 * the builder's node boxes overlap (regions are disjoint, node boxes need not
 * be). Two walks:
 *  - re-trace (the paper's scheme, §4; the GPUs' walk): a closest-hit
 *    traversal from the root for every region, starting where the previous
 *    region ended, without a stack: from each node it goes down to the near
 *    child, across to the sibling or up to the parent, as where it came from
 *    says (Hapala et al. 2011; the parents and child orders of
 *    exabricks.engine.walk_links), so it holds a node and a state in
 *    registers and nothing in memory;
 *  - ordered (-DEB_ORDERED; the CPUs' walk): one traversal per ray with a
 *    private min-heap of nodes and regions keyed by entry distance; popping a
 *    region means every node and region still queued starts behind it, so it
 *    is the next one. Goes on by re-tracing if the heap fills up.
 * Space skipping (paper §4.1): nodes and regions whose value range maps to zero
 * opacity under the current transfer function and brackets no iso-value carry
 * visible = 0 (computed on the host per frame, so a new transfer function needs
 * no BVH rebuild) and are never entered. The flags say which of the two it is
 * (EB_SEEN_VOLUME, EB_SEEN_ISO), and a walk enters what its `want` bits name:
 * a search for iso crossings alone (path_surfaces.cl, occlusion.cl without the
 * medium) passes over the regions whose range brackets no iso-value.
 * Points (probe, central differences, the path integrator, cell location): one
 * descent (eb_descent) with a stack of at most a tree depth of node indices
 * (on PoCL the stackless walk's steps up made central differences 1.3 times
 * slower; the GPU's default frame takes no point query).
 * The trees are checked on load (exabricks.schema): children follow their
 * parent, every node has one parent, and the depth fits EB_STACK_SIZE; every
 * loop here is also bounded by the node and region counts. */
#pragma once
#include "common.h"

/* Box i's corner from an (n, 3) float32 array of corners: the boxes of the
 * BVH, the regions and the cell-location tree are read in the layout their
 * files hold them (grouped by exabricks.engine.device_data, dataset.cl). */
#define EB_CORNER(corners, i) vload3((i), (corners))

/* The visibility flags' bits (exabricks.engine.device_data.SEEN_VOLUME, SEEN_ISO):
 * some volume layer has opacity over the value range; it brackets an iso-value. */
#define EB_SEEN_VOLUME 1
#define EB_SEEN_ISO 2
#define EB_SEEN_ANY (EB_SEEN_VOLUME | EB_SEEN_ISO)

/* exabricks.schema.Bvh on the device: node boxes, (first, count) links, the
 * leaf-order region ids, and the per-frame visibility flags. */
typedef struct {
    __global const float *lower;
    __global const float *upper;
    __global const int2 *link;         /* (first, count); count 0: inner node */
    __global const int *region_index;
    __global const uchar *visible;
    __global const int *parent;        /* parent << 3 | flip << 2 | axis (walk_links) */
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

/* The stackless walk's states at a node: entered (from its parent or its
 * sibling), to be tested; or its subtree done, to be left. Which child of its
 * parent it is says where to go next (eb_walk_up). */
#define EB_TEST 0
#define EB_DONE 1

/* The child of inner node `node` (children first, first + 1) that a ray with
 * 1 / direction inv_dir visits first: the lower one along the node's split
 * axis for a ray running up that axis (exabricks.engine.walk_links). */
EB_INLINE int eb_near_child(eb_bvh bvh, int node, int first, float3 inv_dir)
{
    int bits = bvh.parent[node];
    int axis = bits & 3;
    float d = axis == 0 ? inv_dir.x : (axis == 1 ? inv_dir.y : inv_dir.z);
    return first + ((d >= 0.0f) == ((bits >> 2) & 1));
}

/* The step of a stackless walk from `node`, whose subtree is done: across to
 * its sibling if it was the child the ray visits first (*node the sibling,
 * EB_TEST), else up (*node its parent, EB_DONE); -1 past the root. */
EB_INLINE int eb_walk_up(eb_bvh bvh, int *node, float3 inv_dir)
{
    if (*node == 0)
        return -1;
    int parent = bvh.parent[*node] >> 3;
    int first = bvh.link[parent].x;
    if (*node == eb_near_child(bvh, parent, first, inv_dir)) {
        *node = 2 * first + 1 - *node;
        return EB_TEST;
    }
    *node = parent;
    return EB_DONE;
}

/* The visible region with the smallest entry distance among those the ray
 * overlaps over a non-empty interval after t_cur (and before t_max); -1 if none.
 * On success [*t_in, *t_out] is that overlap, clipped to [t_cur, t_max], with
 * *t_out > *t_in >= t_cur: the caller's next search starts at *t_out, so the
 * walk always advances and visits every region at most once. A closest-hit
 * query without a stack: near child first, and no node entered whose entry
 * lies behind the nearest region found so far. */
inline int eb_next_region(eb_bvh bvh, eb_regions regions, float3 org, float3 inv_dir,
                          float t_cur, float t_max, float *t_in, float *t_out, uchar want)
{
    int best = -1;
    float best_in = t_max, best_out = t_max;
    int node = 0, state = EB_TEST;
    /* each node is tested once and left once */
    for (int steps = 0; state >= 0 && steps <= 2 * bvh.n_nodes; ++steps) {
        if (state == EB_DONE) {
            state = eb_walk_up(bvh, &node, inv_dir);
            continue;
        }
        float2 iv = eb_box_interval(EB_CORNER(bvh.lower, node), EB_CORNER(bvh.upper, node),
                                    org, inv_dir);
        float t_near = fmax(iv.x, t_cur);
        int2 link = bvh.link[node];
        if ((bvh.visible[node] & want) && fmin(iv.y, t_max) > t_near && t_near < best_in) {
            if (link.y == 0) {
                node = eb_near_child(bvh, node, link.x, inv_dir);
                continue;
            }
            for (int i = link.x; i < link.x + link.y; ++i) {
                int r = bvh.region_index[i];
                if (!(regions.visible[r] & want))
                    continue;
                float2 ir = eb_box_interval(EB_CORNER(regions.lower, r),
                                            EB_CORNER(regions.upper, r), org, inv_dir);
                float t0 = fmax(ir.x, t_cur), t1 = fmin(ir.y, t_max);
                if (t1 > t0 && t0 < best_in) {
                    best = r;
                    best_in = t0;
                    best_out = t1;
                }
            }
        }
        state = EB_DONE;
    }
    *t_in = best_in;
    *t_out = best_out;
    return best;
}

#ifdef EB_ORDERED
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
                              float t_min, float t_max, uchar want)
{
    q->size = 0;
    if (!(bvh.visible[0] & want))
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
                              float3 org, float3 inv_dir, float t_cur, float t_max, uchar want)
{
    int2 link = bvh.link[node];
    if (link.y > 0) {
        for (int i = link.x; i < link.x + link.y; ++i) {
            int r = bvh.region_index[i];
            if (!(regions.visible[r] & want))
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
        if (!(bvh.visible[c] & want))
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

#endif

/* The regions along a ray segment [t_min, t_max], front to back: the ordered
 * walk (-DEB_ORDERED), finishing with the re-trace walk from where it stopped
 * if its heap fills up, or the re-trace walk throughout. Every region whose
 * visible bits meet `want` (the same at the start and every step) is
 * returned at most once, with its overlap [*t_in, *t_out] (t_in >= the
 * previous t_out). */
typedef struct {
#ifdef EB_ORDERED
    eb_queue q;
    int retrace;
    int pops;          /* loop bound: each node and region is queued at most once */
#endif
    float t_cur, t_max;
    int visits;        /* loop bound: each region is returned at most once */
} eb_walk;

EB_INLINE void eb_walk_start(eb_walk *w, eb_bvh bvh, float3 org, float3 inv_dir,
                             float t_min, float t_max, uchar want)
{
    w->t_cur = t_min;
    w->t_max = t_max;
    w->visits = bvh.n_regions;
#ifdef EB_ORDERED
    w->retrace = 0;
    w->pops = bvh.n_nodes + bvh.n_regions;
    eb_queue_start(&w->q, bvh, org, inv_dir, t_min, t_max, want);
#endif
}

EB_PROFILED int eb_walk_next(eb_walk *w, eb_bvh bvh, eb_regions regions, float3 org,
                           float3 inv_dir, float *t_in, float *t_out, uchar want)
{
#ifdef EB_ORDERED
    if (!w->retrace) {
        while (w->q.size > 0 && w->pops-- > 0) {
            int item = eb_queue_pop(&w->q);
            if (item >= 0) {
                if (!eb_queue_expand(&w->q, bvh, regions, item, org, inv_dir, w->t_cur, w->t_max, want)) {
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
#endif
    if (w->visits-- <= 0)
        return -1;
    int r = eb_next_region(bvh, regions, org, inv_dir, w->t_cur, w->t_max, t_in, t_out, want);
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
