// Imperfect ray bundles without the rasterizer (--splatter compute, the default): each splat, the
// disk of its radius (bundle.glsl: SplatSource) around its point in the point's triangle's plane,
// finds the bundle lines that cross it in its own direction's bundle, row by row of the bundle's
// pixel grid.
//
// COUNT_SPLATS counts every list's nodes (list_counts); a prefix sum makes them list_offsets; then,
// with list_counts set to every list's end, SCATTER_SPLATS writes each node into its list's slot
// range (its key: depth, and the point | FACING_BIT), counting list_counts back down to the list's
// start. The lists come out exactly as large as they need to be:
// no linked list, no overflow. The merge (resolve_lists.glsl) sorts them, so the order in which
// nodes land in a list does not matter.
//
// The count pass also leaves each splat's lines behind (splat_lines[]): a bit per line of an
// 8 x 8 box of the bundle's pixel grid from the splat's first row and column, and its plane's
// offset, so the scatter writes the nodes without finding the lines again: on a CPU rasterizer
// that search (rows, the neighbour tests) was half the scatter's time. A splat with a line beyond
// the box (a large or edge-on splat: about 2 % on atrium, all of them grown at sharp edges) is
// found again, in a pass of its own over just those splats, with the same code (precise
// arithmetic); should the two passes ever disagree, the scatter counts the mismatch and the host
// says so. A pass of their own because the search, were it in the scatter, would hold up the
// other splats of its SIMD batch, and its code makes every splat's slower: on llvmpipe the
// scatter took 2.5x as long for those 2 %.
//
// A line (i, j) crosses the splat's plane at q; it is in the splat when |q - c| <= r. With
// (du, dv) the offset of the line from the centre c across the bundle and n the plane's normal,
// |q - c|^2 = du^2 + dv^2 + (n_u du + n_v dv)^2 / n_d^2, so in pixels, with everything times n_d^2,
// (n_d^2 + n_u^2) du^2 + 2 n_u n_v du dv + (n_d^2 + n_v^2) dv^2 <= (r n_d)^2: an ellipse, whose rows
// are solved for their span of columns. The depth at a line is the splat plane's (depth_plane),
// the same as the raster splatter's. A line beyond one of the lines that cut the splat (its
// triangle's sharp edges and its flat neighbours') is not in the splat, nor one off the triangle
// beyond the disk's radius before it grew at those lines (scene.glsl: inside_splat); the lines
// are linear in the line's offset in pixels, and its barycentrics are the centre's plus that
// offset mapped back through the triangle's edges as the bundle sees them.
//
// Along a row of the grid a linear test holds on a half-line of columns, so the cut lines and the
// nearer neighbours (below) end each row's span once per row (`clip_row`), not at every line
// (docs/results/decisions.toml: splat-rows). Only what is not linear stays a test per line: a
// grown splat's lines beyond its disk, and a smaller neighbour's reach.
//
// The count pass is two programs, each over a run of the splats as the points pass queued them
// (splat_points.glsl: queue_splat): PLAIN_SPLATS over those that no line cuts, compiled without
// the cut lines, the growth and the smaller neighbours, then the full program over the cut ones.
// llvmpipe runs a SIMD batch through every instruction whether or not a lane needs it, and
// through each loop as often as its largest splat needs: on atrium 42 % of the splats are cut
// (and grown up to twice the radius), and 63 % of the batches of 8 held one
// (docs/results/decisions.toml: plain-splats).

#extension GL_ARB_gpu_shader_int64 : require
#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_SHAPES
#define SLOT_LISTS
#define NODE_KEYS
#define SPLAT_LINE_RECORDS
#define SPLAT_QUEUE
#define SPLAT_TEXELS
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_build.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;  // K N points; with FIND_AGAIN, the splats found again
uniform bool nearest_only;
uniform uint queue_first;  // COUNT_SPLATS: the count pass's first splat in splat_queue[]

// A splat's lines as the count pass found them (splat_lines[], declared in bundle_build.glsl):
// `box` the box's first column | its first row << 16 | FACING_BIT where the splat faces the
// bundle's direction (LINES_FOUND_AGAIN: lines beyond the box, the scatter does not write them;
// no box starts there, as R <= 2^15, gpu_impl/layout.py: SPLAT_LINES_MAX_RESOLUTION), the masks
// a bit per line of the box (row-major, 8 columns a row: mask_high the rows past the fourth), and
// the depth plane of the splat's nodes, so that the scatter reads one record and neither the
// point, its triangle nor the bundle's frame (docs/results/decisions.toml: splat-rows).
#define LINES_BOX 8
#define LINES_FOUND_AGAIN 0xFFFFFFFFu

// Splats of one triangle that overlap put the same node (its plane's depth) on every line they
// share, which the merge would then remove. With nearest_only, a splat leaves a line to a nearer
// splat of the same triangle among the NEIGHBOURS points on either side of it in its direction's
// point order (the stratified sampler's order runs along a space-filling curve, so those are
// mostly its neighbours on the surface). The nearer splat covers the line too, so no hole is made.
// A neighbour j is nearer the line at offset q from this splat's centre c_i when
// (q - e)' M (q - e) < q' M q, e = c_j - c_i, M the ellipse's matrix: dot(q, 2 M e) > e' M e, linear in
// q. A neighbour smaller than this splat (this one grown more at sharp edges) must also reach the
// line: (q - e)' M (q - e) <= E_j, its own ellipse's size, or dot(q, 2 M e) >= q' M q + e' M e - E_j.
// Nearer and reaching, it covers the line: within its disk where this splat's line is within this
// one's, on the triangle where it is beyond. The two splats work it out with different rounding,
// so a splat defers only by a clear MARGIN of the ellipse's size: near a tie both keep the line
// (a redundant node, which the merge removes), never neither. A neighbour no smaller than this
// splat takes the lines on one side of a line across the row, and ends the row's span there; a
// smaller one is tested at every line.
#define NEIGHBOURS 4
#define NEIGHBOUR_SLOTS 8  // 2 NEIGHBOURS
#define MARGIN 1e-3

// Row dy's columns [span.x, span.y] clipped to where dot(vec3(x - cx, dy, 1), line) >= 0: a
// half-line, or the whole row or none where the line does not change along it.
ivec2 clip_row(ivec2 span, vec3 line, float cx, float dy) {
    precise float rest = line.y * dy + line.z;
    precise float t = clamp(cx - rest / line.x, -1e6, 1e6);
    span.x = line.x > 0.0 ? max(span.x, int(ceil(t))) : span.x;
    span.y = line.x < 0.0 ? min(span.y, int(floor(t))) : span.y;
    span.y = line.x == 0.0 && rest < 0.0 ? -1 : span.y;
    return span;
}

#if defined SCATTER_SPLATS
// A node into the slot below its list's cursor. More nodes than counted would take the list
// before's slots: the merge finds the cursors off their lists' starts, and the host says so. Only
// the first list could go below slot 0.
void write_node(uint list, uint64_t key) {
    uint cursor = atomicAdd(list_counts[list], 0xFFFFFFFFu);
    if (cursor == 0u) {
        atomicAdd(counters[COUNTER_MISMATCH], 1u);
        return;
    }
    nodes[cursor - 1u] = key;
}
#endif

// The splat of point `id`: its nodes counted or written; returns the lines it covers (before
// leaving any to a nearer splat).
uint splat(uint id) {
    SplatSource s = splat_source(id);
    uint t = s.triangle;
    vec2 b = s.b;
    vec3 e1 = s.e1, e2 = s.e2, centre = s.centre;
    vec3 n = triangle_normal(t);
    int k = int(id / points_per_direction);
    BundleFrame f = frames[k];
    float nu = dot(n, f.u.xyz), nv = dot(n, f.v.xyz), nd = dot(n, f.d.xyz);
    if (abs(nd) < MIN_COS) {
#if defined COUNT_SPLATS
        splat_lines[id] = SplatLines(0u, 0u, 0u, 0.0, 0.0, 0.0);  // no lines
#endif
        return 0u;
    }
    float w = dot(n, centre);
    uint ref = id | (nd > 0.0 ? FACING_BIT : 0u);
    vec3 plane = depth_plane(f, n, w);

    // The ellipse in the pixel grid: centre c, and A dx^2 + 2 B dx dy + C dy^2 <= E.
    precise vec2 c = bundle_grid_position(f, centre);
    float pixels = 0.5 * float(resolution) / radius;  // per scene unit
    float rp = s.radius * pixels;  // the radius in pixels
    precise float A = nd * nd + nu * nu, B = nu * nv, C = nd * nd + nv * nv, E = rp * rp * nd * nd;
    // The disk before it grew at sharp edges: lines beyond it must lie on the triangle.
    float disk_pixels = splat_radius * pixels, E_disk = disk_pixels * disk_pixels * nd * nd;
    // The neighbours on this triangle (the same plane, so the same ellipse): the linear test of
    // each, dot(q, gradient) > threshold with q the line's offset from this centre in pixels.
    vec2 gradient[NEIGHBOUR_SLOTS];
    float threshold[NEIGHBOUR_SLOTS];
    float reach[NEIGHBOUR_SLOTS];  // a smaller neighbour's: dot(q, gradient) >= q' M q + reach
    bool smaller = false;
    uint first_point = uint(k) * points_per_direction, end_point = first_point + points_per_direction;
    // The triangle's edges in pixels: a neighbour's offset is linear in its barycentrics' offset.
    mat2 edges = grid_edges(f, e1, e2);
    // The splat's shape (scene.glsl: SplatShape), its lines as functions of a line's offset q in
    // pixels: vec3(q, 1) * cuts gives each one's distance plus its slack (scene.glsl: inside_cuts).
#if defined PLAIN_SPLATS
    const bool cut = false, grown = false;
#else
    bool cut = s.cut_lines != 0u, grown = s.radius > splat_radius;
#endif
    mat2 to_barycentrics = mat2(0.0);
    mat3 cuts_a = mat3(0.0), cuts_b = mat3(0.0);
    if (cut) {
        SplatShape shape = splat_shape(t, s.cut_lines);
        to_barycentrics = inverse(edges);
        for (int i = 0; i < 3; i++) {
            vec3 la = shape.lines_a[i], lb = shape.lines_b[i];
            cuts_a[i] = vec3(transpose(to_barycentrics) * la.xy, dot(la, vec3(b, 1.0)) + shape.slack_a[i]);
            cuts_b[i] = vec3(transpose(to_barycentrics) * lb.xy, dot(lb, vec3(b, 1.0)) + shape.slack_b[i]);
        }
    }
    for (int slot = 0; slot < NEIGHBOUR_SLOTS; slot++) {
        uint j = id + uint(slot < NEIGHBOURS ? slot - NEIGHBOURS : slot - NEIGHBOURS + 1);
        uvec4 neighbour = splat_point(clamp(j, first_point, end_point - 1u));
        bool here = nearest_only && j >= first_point && j < end_point && neighbour.x == t;
        vec2 bj = here ? unpackUnorm2x16(neighbour.y) : b;
        float rj = here ? uintBitsToFloat(neighbour.z) * pixels : rp;
        vec2 e = edges * (bj - b);
        float eMe = A * e.x * e.x + 2.0 * B * e.x * e.y + C * e.y * e.y;
        gradient[slot] = 2.0 * vec2(A * e.x + B * e.y, B * e.x + C * e.y);
        threshold[slot] = here ? eMe + MARGIN * E : 3.4e38;
#if defined PLAIN_SPLATS
        reach[slot] = -3.4e38;  // no splat is smaller than an uncut one
#else
        reach[slot] = rj < rp ? eMe - (1.0 - MARGIN) * rj * rj * nd * nd : -3.4e38;
        smaller = smaller || (here && rj < rp);
#endif
    }
    // Where the lines can be: the ellipse's box and, for a splat grown at sharp edges, what
    // covers both the disk before it grew and the triangle, whose lines alone the growth adds.
    vec2 lo = vec2(-1e9), hi = vec2(1e9);
    if (grown) {
        vec2 v0 = edges * -b, v1 = edges * (vec2(1.0, 0.0) - b), v2 = edges * (vec2(0.0, 1.0) - b);
        lo = c + min(vec2(-disk_pixels), min(min(v0, v1), v2));
        hi = c + max(vec2(disk_pixels), max(max(v0, v1), v2));
    }
    // Rows: |dy| <= rp sqrt(1 - n_v^2), the ellipse's half-height.
    precise float half_height = rp * sqrt(max(0.0, 1.0 - nv * nv));
    int y0 = max(0, int(ceil(max(c.y - half_height, lo.y))));
    int y1 = min(resolution - 1, int(floor(min(c.y + half_height, hi.y))));
    int column_lo = int(ceil(max(c.x - rp, lo.x))), column_hi = int(floor(min(c.x + rp, hi.x)));
    uint covered = 0u;
#if defined COUNT_SPLATS
    // The box: LINES_BOX columns from x_min, LINES_BOX rows from y0; a line outside it (a larger
    // splat, or round-off) makes the splat's lines found again.
    int x_min = max(0, column_lo);
    uvec2 mask = uvec2(0u);
    bool kept = true;
#endif
    // The row and column loops test at their end (do-while), without `continue`: llvmpipe runs a
    // loop that tests at its top through its body once more, every lane masked, after the last
    // lane leaves, and a splat's rows and spans are a few lines each (benchmarks/gl_branches.py;
    // docs/results/decisions.toml: plain-splats).
    int y = y0;
    if (y <= y1) do {
        precise float dy = float(y) - c.y;
        precise float disc = B * B * dy * dy - A * (C * dy * dy - E);
        if (!(disc < 0.0)) {
            precise float root = sqrt(disc);
            int x0 = max(max(0, column_lo), int(ceil(c.x + (-B * dy - root) / A)));
            int x1 = min(min(resolution - 1, column_hi), int(floor(c.x + (-B * dy + root) / A)));
            // The splat's columns: the ellipse's, inside every cut line.
            ivec2 inside = ivec2(x0, x1);
            for (int i = 0; cut && i < 3; i++) {
                inside = clip_row(inside, cuts_a[i], c.x, dy);
                inside = clip_row(inside, cuts_b[i], c.x, dy);
            }
            // Those no nearer neighbour takes (one no smaller than this splat: reach -3.4e38).
            ivec2 kept_span = inside;
            for (int slot = 0; slot < NEIGHBOUR_SLOTS; slot++) {
                vec3 nearer = vec3(-gradient[slot], threshold[slot]);  // dot(q, gradient) <= threshold
                kept_span = reach[slot] == -3.4e38 ? clip_row(kept_span, nearer, c.x, dy) : kept_span;
            }
#if defined COUNT_COVERED
            ivec2 walked = inside;  // the studies' sum counts the lines neighbours take too
#else
            ivec2 walked = kept_span;
#endif
            int x = walked.x;
            if (x <= walked.y) do {
                precise vec2 q = vec2(float(x) - c.x, dy);
                float qMq = A * q.x * q.x + 2.0 * B * q.x * q.y + C * q.y * q.y;
                // Beyond the disk before it grew, the line must cross the triangle.
                bool line = !(grown && qMq > E_disk && !inside_triangle(b + to_barycentrics * q));
                if (line) covered++;
                line = line && x >= kept_span.x && x <= kept_span.y;
                if (smaller) {
                    bool nearer = false;  // a smaller splat of this triangle nearer the line, reaching it
                    for (int slot = 0; slot < NEIGHBOUR_SLOTS; slot++) {
                        float g = dot(q, gradient[slot]);
                        nearer = nearer || (g > threshold[slot] && g >= qMq + reach[slot]);
                    }
                    line = line && !nearer;
                }
                if (line) {
                    uint list = pixel_list(k, ivec2(x, y));
#if defined COUNT_SPLATS
                    atomicAdd(list_counts[list], 1u);
                    uint column = uint(x - x_min), row = uint(y - y0);
                    kept = kept && x >= x_min && column < LINES_BOX && row < LINES_BOX;
                    if (kept) mask[row / 4u] |= 1u << (row % 4u * LINES_BOX + column);
#else
                    write_node(list, node_key(dot(plane, vec3(1.0, float(x), float(y))), ref));
#endif
                }
            } while (++x <= walked.y);
        }
    } while (++y <= y1);
#if defined COUNT_SPLATS
    if (kept) {
        uint box = uint(x_min) | uint(y0) << 16 | (ref & FACING_BIT);
        splat_lines[id] = SplatLines(box, mask.x, mask.y, plane.x, plane.y, plane.z);
    } else {
        splat_lines[id].box = LINES_FOUND_AGAIN;
        found_again[atomicAdd(counters[COUNTER_FOUND_AGAIN], 1u)] = id;
    }
#endif
    return covered;
}

#if defined SCATTER_SPLATS
// Node keys for the lines the count pass kept for splat `id`.
void scatter(uint id) {
    SplatLines lines = splat_lines[id];
    if (lines.box == LINES_FOUND_AGAIN) return;
    int k = int(id / points_per_direction);
    vec3 plane = vec3(lines.depth, lines.depth_x, lines.depth_y);
    uint ref = id | (lines.box & FACING_BIT);
    ivec2 origin = ivec2(lines.box & 0xFFFFu, (lines.box & ~FACING_BIT) >> 16);
    // One loop over the box's 64 bits, tested at its end as the count pass's loops are: a SIMD
    // batch runs it as often as its lane with the most lines needs. A loop over each half ran as
    // often as the most lines in the first half and then in the second, and the scatter took a
    // tenth longer on llvmpipe (docs/results/decisions.toml: plain-splats).
    uvec2 mask = uvec2(lines.mask_low, lines.mask_high);
    if (mask != uvec2(0u)) do {
        uint bit = mask.x != 0u ? uint(findLSB(mask.x)) : 32u + uint(findLSB(mask.y));
        ivec2 pixel = origin + ivec2(bit % LINES_BOX, bit / LINES_BOX);
        write_node(pixel_list(k, pixel), node_key(dot(plane, vec3(1.0, vec2(pixel))), ref));
        if (mask.x != 0u) mask.x &= mask.x - 1u; else mask.y &= mask.y - 1u;
    } while (mask != uvec2(0u));
}
#endif

#if defined COUNT_COVERED
shared uint covered_by_group;
#endif

void main() {
    uint id = linear_id();
#if defined COUNT_COVERED
    // Every line a splat covers, summed (COUNTER_COVERED): the nodes there would be without
    // merging, what the splat size costs (studies ask for it: a workgroup barrier costs a CPU
    // rasterizer more than the sum is worth in a plain build). One atomic per workgroup.
    if (gl_LocalInvocationIndex == 0u) covered_by_group = 0u;
    barrier();
    uint covered = id < invocations ? splat(splat_queue[queue_first + id]) : 0u;
    atomicAdd(covered_by_group, covered);
    barrier();
    if (gl_LocalInvocationIndex == 0u) atomicAdd(counters[COUNTER_COVERED], covered_by_group);
#elif defined FIND_AGAIN
    if (id < invocations) splat(found_again[id]);  // the scatter of the splats beyond their box
#elif defined SCATTER_SPLATS
    if (id < invocations) scatter(id);
#else
    if (id < invocations) splat(splat_queue[queue_first + id]);
#endif
}

#endif
