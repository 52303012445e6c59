// One step of a path over the frame's bundles, shared by the eye paths (eye_paths.glsl) and the
// light paths (light_paths.glsl): from vertex x (on `triangle`, NO_TRIANGLE where it lies on none;
// geometric normal ng, on the side the path leaves) along bundle k's direction (forward: +d, else
// -d) to the next vertex.
//
// The next vertex: where the ray from the vertex along omega meets the frame's bundle. No line
// passes through the vertex; the four around it (R x R lines, h = 2 radius / R apart) pass up
// to a pixel beside it, and each meets surfaces the ray may or may not. Each line offers the
// first node beyond the vertex whose plane the ray reaches, and the ray's own point on that
// plane; the ray lands on the nearest of them that lies on its node's surface (inside its
// triangle, a splat's triangle too), or on a triangle that a walk across the node's
// triangle's edges reaches (walk_surface). A line whose met surface the ray passes outside of
// offers the next node on it instead. A point on a surface another line meets nearer is behind
// that surface (the far wall beside a block), so all four are looked at. One line's node
// taken where it lies put the next vertex half a pixel off on average, towards the open side, and
// lost the light of lines passing beside a concave edge: +2 % and -1 % of cornell-box's and the
// furnace's indirect light at R = 64 (docs/results/decisions.toml: four-lines).
//
// Where no point lies on a surface, the ray passes between the surfaces the lines meet (or
// their walks stopped short), and the lines vote: the ray meets a surface where
// more lines meet one than leave the scene, on a tie where the line nearest the vertex among
// them does, and lands on the node of the nearest line that meets one, where it lies. Every line
// that meets a surface here meets one the ray misses, so the ray leaves more often than the
// lines do: in exact bundles of the parts scene, rays with one of four lines meeting a surface
// left 91-95 % of the time. The line on the vertex's open side, which decided alone before, made
// the parts' direct sky light 1-3 % short at every R (docs/results/decisions.toml: lines-vote). A
// line below the vertex's tangent plane with no node behind the vertex does not vote: it passes
// outside whatever the vertex lies on (under a floor, then behind the wall the ray meets), so
// its leaving the scene says nothing of the ray's. Counted, it lost the furnace's light at
// concave edges. Nor does a line behind the front of a surface another line meets: beside a
// vertex within a pixel of a wall it passes outside the closed room, where the floor's splats
// reach past the wall (concave edges do not cut splats), and its leaving says nothing of the
// ray's. A front that the ray meets ahead, which a line under the plane meets before it crosses
// the plane (the wall's splats reaching below the floor), is not a node behind the vertex either.
// With both counted, 2.3-2.9 % of the lookups from a room's floor by its wall left the room;
// with the second still counted, 0.27-0.45 %; now 0.10-0.25 % (exact bundles: 0.03 %;
// tests/test_bundle_metrics.py). A line in front of a surface's back (beside a step the ray may
// pass over) still votes: counted out, it made lookups between the parts scene's pieces hit more
// often than their rays.

uniform float self_hit_bias;  // in bundle pixels, see below

// Whether the lines around vertex x (geometric normal ng, towards the side the ray leaves; on
// `triangle`, NO_TRIANGLE where it lies on none) skip a node as a splat of the surface x lies on:
// - x lies in the splat's cylinder (its radius across and along its normal) and the two face the
//   same way (normals within 60 degrees: OWN_SPLAT_COS, which says why not 90). A splat stands
//   in for its surface a radius around its centre; in its own triangle's plane it stands off a
//   curved surface (r^2 / 2 rho at curvature radius rho) and would shadow the vertex it
//   represents. A splat of another surface (x on a triangle) stays where y, the ray's point on
//   its plane, lies in the splat's own triangle: there the splat is that surface, a real one in
//   front of x. Skipped there, the light's splats let the ceiling above cornell-box's light, 0.01
//   over it, see the room through the light, and the ceiling's indirect light there was twice
//   Mitsuba's (docs/results/decisions.toml: another-surface-in-front).
// - it is a splat of x's smooth surface whose centre lies behind x's tangent plane, within
//   2 (r + h) of x (a line passes up to a pixel's diagonal beside x, and meets a splat up to
//   its radius from its centre): the surface it stands for is one the ray cannot reach, while
//   its disk, tangent elsewhere on a convex surface, stands out over that plane where the lines
//   beside x meet it, and they outvoted the ray. Lookups on the parts scene (N = 1048576,
//   R = 256) let through 0.986 of the sky light that rays do at the camera's vertices and 0.962 at
//   the second ones, against 0.996 and 0.998 for exact bundles
//   (docs/results/decisions.toml: own-surface-behind-tangent-plane). A splat
//   of another surface behind the plane may be one the ray meets in front of it (the floor beside
//   a column), and stays.
bool own_surface(uint ref, vec3 x, vec3 ng, float h, uint triangle, vec3 y) {
#if NODE_REFERENCE == NODE_SPLAT_POINT
    uint t = ref_triangle(ref);
    vec3 n = triangle_normal(t);
    SplatSource s = splat_source(ref);
    vec3 q = x - s.centre;
    float along = dot(q, n), reach = 2.0 * (s.radius + h);
    bool same_surface = triangle == NO_TRIANGLE || triangle_surface(t) == triangle_surface(triangle);
    bool in_cylinder = dot(n, ng) > OWN_SPLAT_COS && abs(along) <= s.radius && dot(q, q) - along * along <= s.radius * s.radius;
    if (in_cylinder && (same_surface || !inside_triangle(plane_barycentrics(s.p0, s.e1, s.e2, y)))) return true;
    return triangle != NO_TRIANGLE && same_surface && dot(q, ng) >= 0.0 && dot(q, q) <= reach * reach;
#else
    return false;
#endif
}

// How far a step walks across a met node's triangle's edges (walk_surface): across edges that pass
// within WALK_REACH bundle pixels of where the line met the node, at most MAX_WALK_HOPS
// triangles. The ray's point is within a pixel and a half of the line, so the walk reaches it
// across triangles of any size; a count of 4 triangles stopped it short on triangles smaller than
// a pixel: on atrium at R = 128 it left 5.0 % of next hits wrong, against 1.3 %. The distance
// costs a bounce a third more time there, three quarters more with splats, whose walks start at
// the splat's centre (docs/results/decisions.toml: walk-by-distance). (On the parts scene at
// R = 256, one hop left the second lookups from exact hits letting through 0.989 of the sky light
// that rays do, four 0.999: docs/results/decisions.toml, walk-the-met-surface.)
// evalkit/metrics/bundles.py mirrors both.
const float WALK_REACH = 2.0;
const uint MAX_WALK_HOPS = 64u;
const uint WALK_MET = 0u, WALK_OUTSIDE = 1u, WALK_OPEN = 2u;
struct SurfaceWalk {
    uint end;       // WALK_MET, WALK_OUTSIDE or WALK_OPEN
    uint triangle;  // WALK_MET: the triangle the ray meets
    float t;        // WALK_MET: the distance to it along omega
};

// Where the ray's point on the plane of the node `ref` (at distance s along omega from the vertex
// x), met by a line beside the vertex, lies:
// - on the node's surface (WALK_MET, NO_TRIANGLE: the node itself): inside its triangle, a splat's
//   too. A splat stands for its triangle, which the line met near it: inside the triangle the ray
//   meets that surface exactly, as in a perfect bundle (docs/results/decisions.toml:
//   splats-stand-for-triangles). Its disk is not the surface: within the disk but off the
//   triangle, the walk below finds where the ray meets the mesh. A disk taken as the surface there
//   stood out past smooth outlines and bends, and atrium's indirect light with imperfect bundles
//   was 3 % below perfect bundles' at the poster's settings, 11 % with the irradiance
//   precomputed per splat point (docs/results/decisions.toml: splat-disk-not-surface).
// - else the walk crosses the edge of the node's triangle that the point lies beyond, to the
//   triangle there, and takes the ray's point on that one's plane, as far as WALK_REACH pixels
//   from the line's node `met` (h: a pixel).
//   Inside one, the ray meets it there, exactly (WALK_MET). Without the walk the ray landed on a
//   farther surface another line met, or by the lines' vote, where a line met the neighbour of
//   the triangle the ray meets.
// - across an outline edge (the triangle beyond faces the other way along omega, or there is
//   none), or to a plane the ray reaches only behind it, or to the vertex's own triangle, the ray
//   passes outside that surface (WALK_OUTSIDE): the line's meeting it says nothing of the ray,
//   which goes on to whatever the line meets behind it. Such lines outvoted the ray where it
//   leaves past a part's outline: the parts scene's indirect light was 0.985 of Mitsuba's
//   (docs/results/decisions.toml: perfect-parts-deficit.
// - still beyond the last triangle's edge (WALK_OPEN): undecided; the line meets a surface.
SurfaceWalk walk_surface(uint ref, vec3 x, vec3 omega, float s, uint own, vec3 met, float h) {
    const SurfaceWalk outside = SurfaceWalk(WALK_OUTSIDE, NO_TRIANGLE, 0.0);
    float reach2 = WALK_REACH * WALK_REACH * h * h;
    // A hop's triangle's corners and normal are the ones the hop before it read.
    uint t = ref_triangle(ref);
    vec3 p0, p1, p2;
    triangle_corners(t, p0, p1, p2);
    vec3 normal = triangle_normal(t);
    for (uint hop = 0u;; hop++) {
        vec2 b = plane_barycentrics(p0, p1 - p0, p2 - p0, x + s * omega);
        vec3 w = vec3(1.0 - b.x - b.y, b.x, b.y);
        uint corner = w.x <= w.y && w.x <= w.z ? 0u : (w.y <= w.z ? 1u : 2u);
        // Inside, up to round-off (scene.glsl: inside_triangle); at the first, the node itself.
        if (w[corner] >= -1e-4) return SurfaceWalk(WALK_MET, hop == 0u ? NO_TRIANGLE : t, s);
        // The edge to cross, opposite that corner, must pass within reach of the line's node.
        vec3 a = corner == 0u ? p1 : (corner == 1u ? p2 : p0), e = (corner == 0u ? p2 : (corner == 1u ? p0 : p1)) - a;
        vec3 off = a + clamp(dot(met - a, e) / max(dot(e, e), 1e-30), 0.0, 1.0) * e - met;
        if (hop == MAX_WALK_HOPS || dot(off, off) > reach2) return SurfaceWalk(WALK_OPEN, NO_TRIANGLE, 0.0);
        uint across = triangle_across(t, (corner + 1u) % 3u);  // the edge opposite that corner
        if (across == NO_TRIANGLE) return outside;
        uint u = across & ~TRIANGLE_TURNED;
        vec3 n = triangle_normal(u);
        bool turned = (across & TRIANGLE_TURNED) != 0u;
        if (u == own || ((dot(n, omega) < 0.0) != turned) != (dot(normal, omega) < 0.0)) return outside;
        triangle_corners(u, p0, p1, p2);
        s = dot(n, p0 - x) / dot(n, omega);
        if (!(s > 0.0) || isinf(s)) return outside;
        t = u;
        normal = n;
    }
}

struct BundleStep {
    bool leaves;     // the direction leaves x's geometric surface (else the path would enter it)
    uint hit;        // the node reached, NO_NODE where the ray leaves the scene
    BundleHit node;  // what it is (when hit != NO_NODE)
    vec3 geometric;  // its triangle's geometric normal
};

BundleStep bundle_step(int k, bool forward, vec3 x, vec3 ng, uint triangle) {
    BundleFrame f = frames[k];
    vec3 omega = forward ? f.d.xyz : -f.d.xyz;
    float cg = dot(ng, f.d.xyz);
    // With a shading normal, omega may point below the geometric surface: the path would enter it.
    bool leaves = forward ? cg > 0.0 : cg < 0.0;
    vec2 grid = bundle_grid_position(f, x);
    ivec2 corner = ivec2(floor(grid));
    vec2 offset = grid - vec2(corner);
    // Nodes up to the vertex's depth along a line are behind it; so are those up to where the line
    // crosses the vertex's tangent plane, should it cross ahead (a line below that plane). A
    // further self-hit bias of self_hit_bias h covers float32 depths: occluders nearer than that
    // to the vertex are missed.
    float h = 2.0 * radius / float(resolution);  // the lines' spacing
    float bias = self_hit_bias * h;
    uint hit = NO_NODE, near_hit = NO_NODE;  // near_hit: the node of the nearest line that meets a surface
    uint hit_triangle = NO_TRIANGLE;         // the triangle a walk met the ray on (NO_TRIANGLE: the node)
    int meet_votes = 0, leave_votes = 0;
    bool near_voter_meets = false;            // the nearest voting line's vote
    vec3 near_origin = vec3(0.0);
    float hit_t = 0.0, near_distance = 4.0, near_voter = 4.0;  // squared distances in grid units
    // Each line's node of a surface smaller than a pixel that the ray's point misses (a blocker, see
    // below), NO_NODE if none: the node, the ray's distance to its plane, the line's bilinear weight.
    uint blocker[4] = uint[4](NO_NODE, NO_NODE, NO_NODE, NO_NODE);
    // Each line: whether it votes and whether it meets a surface, its point at the vertex's depth,
    // and the front (normal, node) of the surface it meets where the ray meets that side (else 0).
    bool voter[4] = bool[4](false, false, false, false), meets[4] = bool[4](false, false, false, false);
    vec3 at_vertex[4], front_normal[4], front_node[4];
    float line_distance[4] = float[4](4.0, 4.0, 4.0, 4.0);
    for (int c = 0; c < 4; c++) at_vertex[c] = front_normal[c] = front_node[c] = vec3(0.0);
    float blocker_t[4] = float[4](0.0, 0.0, 0.0, 0.0), weight[4] = float[4](0.0, 0.0, 0.0, 0.0);
    for (int c = 0; c < 4 && leaves; c++) {
        ivec2 pixel = corner + ivec2(c & 1, c >> 1);
        if (any(lessThan(pixel, ivec2(0))) || any(greaterThanEqual(pixel, ivec2(resolution)))) continue;
        uint list = pixel_list(k, pixel);
        vec3 origin = line_origin(k, pixel);
        float depth = dot(x - origin, f.d.xyz);
        float crossing = depth + dot(ng, x - (origin + depth * f.d.xyz)) / cg;
        float bound = forward ? max(depth, crossing) + bias : min(depth, crossing) - bias;
        // The nearest node beyond the bound along omega: a binary search of the sorted depths.
        uint first = list_first(list), last = list_end(list);
        uint lo = first, hi = last;
        while (lo < hi) {
            uint mid = (lo + hi) / 2u;
            if (forward ? node_depth(mid) <= bound : node_depth(mid) < bound) lo = mid + 1u; else hi = mid;
        }
        uint node = forward ? (lo < last ? lo : NO_NODE) : (lo > first ? lo - 1u : NO_NODE);
        // Not a voter: a line under the vertex's tangent plane with no node behind the vertex. A
        // front the ray meets ahead, which the line meets before it crosses that plane, is not one:
        // the line passes behind it (under a floor, through the wall's splats that reach below it).
        // The nodes before the bound are looked at from the far end: one behind the vertex decides.
        voter[c] = forward ? crossing <= depth : crossing >= depth;
        for (uint m = forward ? first : last; !voter[c] && (forward ? m < lo : m > lo); forward ? m++ : m--) {
            uint before = forward ? m : m - 1u;
            vec3 plane_normal = triangle_normal(ref_triangle(node_ref(before)));
            bool behind = forward ? node_depth(before) <= depth : node_depth(before) >= depth;
            float gap = dot(plane_normal, origin + node_depth(before) * f.d.xyz - x);
            voter[c] = behind || !(dot(plane_normal, omega) < 0.0 && gap < 0.0);
        }
        at_vertex[c] = origin + depth * f.d.xyz;
        vec2 to_line = vec2(c & 1, c >> 1) - offset;
        float distance = dot(to_line, to_line);
        line_distance[c] = distance;
        weight[c] = (1.0 - abs(to_line.x)) * (1.0 - abs(to_line.y));
        // A node whose plane the ray cannot reach (the plane lies behind the vertex, or through
        // it) is on the line only because the line passes beside the vertex: the next one is
        // taken. Near a concave edge a line may pass behind the other surface (a floor vertex's
        // line behind the wall) and meet its back: the furnace's 1-bounce indirect light at R = 32
        // was 5.7 % short before (tests/test_renderer.py). A splat lies in its triangle's plane.
        // A splat of the vertex's own surface is skipped too: on a curved surface it stands off
        // the vertex and shadowed it (parts scene, N = 65536, R = 256: indirect light 0.23 of
        // Mitsuba's with it, 0.51 without; docs/results/decisions.toml: own-surface-cylinder).
        while (node != NO_NODE) {
            uint ref = node_ref(node);
            vec3 plane_normal = triangle_normal(ref_triangle(ref));
            float gap = dot(plane_normal, origin + node_depth(node) * f.d.xyz - x), along = dot(plane_normal, omega);
            float t = gap / along;
            SurfaceWalk walk = SurfaceWalk(WALK_OUTSIDE, NO_TRIANGLE, 0.0);
            vec3 met = origin + node_depth(node) * f.d.xyz;
            if (gap * along > 0.0 && !own_surface(ref, x, ng, h, triangle, x + t * omega)) walk = walk_surface(ref, x, omega, t, triangle, met, h);
            if (walk.end != WALK_OUTSIDE) {
                // No nearer than the best so far (on its plane, usually): it cannot win.
                if (walk.end == WALK_MET && (hit == NO_NODE || walk.t < hit_t * (1.0 - 1e-5))) {
                    hit = node;
                    hit_t = walk.t;
                    hit_triangle = walk.triangle;
                }
                if (walk.end == WALK_OPEN && smaller_than_pixel(ref, h)) {
                    blocker[c] = node;
                    blocker_t[c] = t;
                }
                meets[c] = true;
                if (along < 0.0) {
                    front_normal[c] = plane_normal;
                    front_node[c] = origin + node_depth(node) * f.d.xyz;
                }
                if (distance < near_distance) {
                    near_hit = node;
                    near_origin = origin;
                    near_distance = distance;
                }
                break;
            }
            node = forward ? (node + 1u < last ? node + 1u : NO_NODE) : (node > first ? node - 1u : NO_NODE);
        }
    }
    for (int c = 0; c < 4; c++) {
        // Not a voter either: a line behind the front of a surface another line meets (see above).
        for (int m = 0; m < 4; m++) voter[c] = voter[c] && dot(front_normal[m], at_vertex[c] - front_node[m]) >= 0.0;
        if (meets[c]) meet_votes++; else if (voter[c]) leave_votes++;
        if ((meets[c] || voter[c]) && line_distance[c] < near_voter) {
            near_voter = line_distance[c];
            near_voter_meets = meets[c];
        }
    }
    // A surface smaller than a pixel that lines meet nearer than the ray's point on a farther one
    // may stand in front of it: the ray's miss of that small triangle or splat says nothing of the
    // surface it is part of (a column of facets a sixth of a pixel wide, a curtain). It does, where
    // the lines that meet it weigh more than half of all four, bilinearly: the ray then lands on
    // the heaviest of those lines' nodes, where it lies. Without this, 9 % of the lookups from
    // atrium's eye vertices at R = 128 landed over half a pixel behind the ray's first surface, and
    // 1.6 % in front of it; with it, 5.6 and 2.7 % (docs/results/decisions.toml: smaller-than-a-pixel).
    bool on_surface = hit != NO_NODE;
    if (on_surface) {
        float nearer = 0.0, total = 0.0, heaviest = 0.0;
        int chosen = -1;
        for (int c = 0; c < 4; c++) {
            total += weight[c];
            if (blocker[c] == NO_NODE || blocker_t[c] >= hit_t * (1.0 - 1e-3)) continue;
            nearer += weight[c];
            if (weight[c] > heaviest) {
                heaviest = weight[c];
                chosen = c;
            }
        }
        if (nearer > 0.5 * total) {
            hit = blocker[chosen];
            near_origin = line_origin(k, corner + ivec2(chosen & 1, chosen >> 1));
            on_surface = false;
        }
    }
    if (hit == NO_NODE && (meet_votes > leave_votes || (meet_votes == leave_votes && near_voter_meets))) hit = near_hit;
    BundleHit node = BundleHit(0u, vec3(0.0), vec3(0.0), vec3(0.0));
    vec3 node_geometric = vec3(0.0);
    if (hit != NO_NODE) {
        // The ray's point on the node's surface; off it (the lines' vote), the node where it
        // lies: a small curved facet's plane carried to the ray put the vertex inside neighbouring
        // parts (-18 % of the parts scene's indirect light at R = 128).
        vec3 y = on_surface ? x + hit_t * omega : near_origin + node_depth(hit) * f.d.xyz;
        node = on_surface && hit_triangle != NO_TRIANGLE ? triangle_hit(y, hit_triangle) : bundle_hit(y, node_ref(hit));
        node_geometric = triangle_normal(node.triangle);
    }
    return BundleStep(leaves, hit, node, node_geometric);
}
