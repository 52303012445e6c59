// The paraboloid map of a hemisphere (Brabec et al. 2002), as imperfect shadow maps use them
// (Ritschel et al. 2008): a direction at angle theta from the axis n lands at tan(theta / 2) from
// the map's centre, in the unit disk, so one square map covers a light vertex's whole front.

// The tangent frame of axis n: a fixed function of n, so the raster pass and the lookup agree.
mat3 paraboloid_frame(vec3 n) {
    vec3 helper = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    vec3 t = normalize(cross(n, helper));
    return mat3(t, cross(n, t), n);
}

// Unit direction v in the tangent frame of axis n: (t, b, n) components.
vec3 paraboloid_local(vec3 n, vec3 v) {
    return v * paraboloid_frame(n);
}

// Where a local direction lands in the map's [-1, 1]^2 (the unit disk: local.z >= 0).
vec2 paraboloid_position(vec3 local) {
    return local.xy / (1.0 + local.z);
}

// The world direction that lands at q in the map of axis n (|q| <= 1): the inverse of the above.
vec3 paraboloid_direction(vec3 n, vec2 q) {
    float s = dot(q, q);
    return paraboloid_frame(n) * (vec3(2.0 * q, 1.0 - s) / (1.0 + s));
}
