// The paraboloid map of a hemisphere (Brabec et al. 2002), as imperfect shadow maps use them
// (Ritschel et al. 2008): a direction at angle theta from the axis n lands at tan(theta / 2) from
// the map's centre, in the unit disk, so one square map covers a light vertex's whole front.

// Unit direction v in the tangent frame of axis n: (t, b, n) components. The frame is a fixed
// function of n, so the raster pass and the lookup agree.
vec3 paraboloid_local(vec3 n, vec3 v) {
    vec3 helper = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    vec3 t = normalize(cross(n, helper)), b = cross(n, t);
    return vec3(dot(v, t), dot(v, b), dot(v, n));
}

// Where a local direction lands in the map's [-1, 1]^2 (the unit disk: local.z >= 0).
vec2 paraboloid_position(vec3 local) {
    return local.xy / (1.0 + local.z);
}
