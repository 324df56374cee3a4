// material.glsl: a glTF metallic-roughness material lit by one sun and an ambient term
// (docs/renderer.md, "Materials"). vt.frag and reference.frag both shade with it, each from what it
// sampled itself: the VT pass from its layers' atlases, the reference from its own textures of the
// same layers. Included after vt_sample.glsl, under VT_MATERIAL, with VT_LAYERS texels handed in
// and, for each map the store has a layer for, its index among them: VT_NORMAL_MAP,
// VT_MR_MAP (G roughness, B metallic), VT_OCCLUSION_MAP (R), VT_EMISSIVE_MAP (sRGB colour).
// A map the store has no layer for takes glTF's value for "no map": a flat normal, no occlusion,
// no emission; without a metallic-roughness layer the surface is a rough dielectric (metallic 0,
// roughness 1: the factors are not stored, docs/atlas.md).

in vec3 v_normal;  // the vertex normal, world frame, not normalised; zero where the mesh has none
in vec3 v_eye;     // the fragment's position relative to the camera, world units

// Toward the sun, world frame (z up), and the light it brings; the ambient term stands for the sky.
const vec3 mat_sun_direction = normalize(vec3(-0.5, -0.4, 0.75));
const float mat_sun_irradiance = 2.4;
const float mat_ambient = 0.3;
const float mat_pi = 3.14159265;

// The surface frame of the fragment, from derivatives (no stored tangents): the geometric normal
// (the vertex normal, or the facet's where the mesh has none, turned to the viewer's side for
// two-sided cards), and tangent and bitangent along the texture's u and up its image (glTF's +Y of a
// normal map), mirrored where the texture coordinates are. Call it in uniform control flow, before
// any discard: it takes derivatives.
struct MatFrame {
    vec3 t, b, n;
};

MatFrame mat_frame(vec2 texel) {
    vec3 p_dx = dFdx(v_eye), p_dy = dFdy(v_eye);
    vec2 uv_dx = dFdx(texel), uv_dy = dFdy(texel);
    vec3 facet = cross(p_dx, p_dy);  // toward the viewer
    vec3 n = dot(v_normal, v_normal) > 0.0 ? normalize(v_normal) : normalize(facet);
    if (!gl_FrontFacing && dot(v_normal, v_normal) > 0.0) n = -n;
    // dp/du by Cramer's rule on the screen-space derivatives; v grows down the image.
    float det = uv_dx.x * uv_dy.y - uv_dy.x * uv_dx.y;
    vec3 t = uv_dy.y * p_dx - uv_dx.y * p_dy;
    t *= det < 0.0 ? -1.0 : 1.0;
    t -= n * dot(n, t);
    float tl = dot(t, t);
    // Degenerate texture coordinates (a solid colour's cell, a stretched edge): any tangent.
    vec3 other = abs(n.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0);
    t = tl > 0.0 && !isinf(tl) && !isnan(tl) ? t * inversesqrt(tl) : normalize(cross(other, n));
    MatFrame f;
    f.t = t;
    f.n = n;
    f.b = cross(n, t) * (det > 0.0 ? -1.0 : 1.0);
    return f;
}

// Linear radiance of the material with base colour `base` (linear) and the layers' filtered texels.
vec3 mat_shade(MatFrame f, vec3 base, vec4 maps[VT_LAYERS]) {
    vec3 n = f.n;
#ifdef VT_NORMAL_MAP
    vec3 m = maps[VT_NORMAL_MAP].rgb * 2.0 - 1.0;
    vec3 bent = f.t * m.x + f.b * m.y + f.n * m.z;
    if (dot(bent, bent) > 1e-8) n = normalize(bent);
#endif
    float roughness = 1.0, metallic = 0.0, occlusion = 1.0;
    vec3 emissive = vec3(0.0);
#ifdef VT_MR_MAP
    roughness = maps[VT_MR_MAP].g;
    metallic = clamp(maps[VT_MR_MAP].b, 0.0, 1.0);
#endif
#ifdef VT_OCCLUSION_MAP
    occlusion = clamp(maps[VT_OCCLUSION_MAP].r, 0.0, 1.0);
#endif
#ifdef VT_EMISSIVE_MAP
    emissive = maps[VT_EMISSIVE_MAP].rgb;
#endif
    // glTF 2.0's BRDF (its specification, appendix B): GGX, Smith's height-correlated visibility,
    // Schlick's Fresnel; roughness kept above 0.05 so that a mirror's highlight stays finite.
    float alpha = max(roughness, 0.05);
    alpha *= alpha;
    float a2 = alpha * alpha;
    vec3 l = mat_sun_direction;
    vec3 v = normalize(-v_eye);
    vec3 h = normalize(l + v);
    float nl = max(dot(n, l), 0.0), nv = max(dot(n, v), 1e-4), nh = max(dot(n, h), 0.0), vh = max(dot(v, h), 0.0);
    vec3 f0 = mix(vec3(0.04), base, metallic);
    vec3 c_diff = mix(base, vec3(0.0), metallic);
    vec3 fresnel = f0 + (1.0 - f0) * pow(1.0 - vh, 5.0);
    float dd = nh * nh * (a2 - 1.0) + 1.0;
    float d = a2 / (mat_pi * dd * dd);
    float vis = 0.5 / max(nl * sqrt(nv * nv * (1.0 - a2) + a2) + nv * sqrt(nl * nl * (1.0 - a2) + a2), 1e-6);
    vec3 direct = ((1.0 - fresnel) * c_diff / mat_pi + fresnel * d * vis) * (mat_sun_irradiance * nl);
    vec3 ambient = mat_ambient * occlusion * (c_diff + f0);
    return direct + ambient + emissive;
}
