"""GLSL sources of the renderer (GLSL 330 core). Each program is assembled by `source()`.

Skinning: vertex i's blended transform is sum_j w_ij * A_j, either over all handles with the
weights as attributes (`dense_skin_chunk`, small m) or over the vertex's (weight, handle) pairs
(`skin_chunk`: attributes, then any spilled into the `u_weights` texture); A_j (3x4, rows u_rows[3j..3j+2])
is handle j's affine transform, i.e. block j of T (4m, 3) transposed. Positions are A [v 1]
(= row i of M @ T), normals are the cofactor of A's linear part times the rest normal.
"""

SKIN_COMMON = """
layout(std140) uniform Handles { vec4 u_rows[3 * HANDLES]; };

vec3 apply_affine(vec4 r0, vec4 r1, vec4 r2, vec3 p) {
    vec4 h = vec4(p, 1.0);
    return vec3(dot(r0, h), dot(r1, h), dot(r2, h));
}

vec3 transform_normal(vec4 r0, vec4 r1, vec4 r2, vec3 n) {
    // Columns of the linear part A; cofactor(A) = det(A) A^-T has columns c1xc2, c2xc0, c0xc1.
    vec3 c0 = vec3(r0.x, r1.x, r2.x), c1 = vec3(r0.y, r1.y, r2.y), c2 = vec3(r0.z, r1.z, r2.z);
    return mat3(cross(c1, c2), cross(c2, c0), cross(c0, c1)) * n;
}
"""

SKIN_SPILL = """
uniform sampler2D u_weights;   // RG32F texel k: (weight, handle index)
in uvec2 in_span;              // spilled pairs of this vertex: first texel, count
void add_spilled(inout vec4 r0, inout vec4 r1, inout vec4 r2) {
    int first = int(in_span.x);
    int last = first + int(in_span.y);
    for (int k = first; k < last; ++k) {
        vec2 pair = texelFetch(u_weights, ivec2(k & (WEIGHTS_WIDTH - 1), k >> WEIGHTS_SHIFT), 0).xy;
        int j = 3 * int(pair.y);
        r0 += pair.x * u_rows[j];
        r1 += pair.x * u_rows[j + 1];
        r2 += pair.x * u_rows[j + 2];
    }
}
"""


def dense_skin_chunk(handles: int) -> str:
    """GLSL of blend_transform() over every handle, weights from attributes in_dense<g> (vec4):
    uniform (broadcast) reads of the handles, no gathers: the fastest form for small m."""
    lines = [SKIN_COMMON]
    lines += [f"in vec4 in_dense{g};" for g in range(-(-handles // 4))]
    lines.append("void blend_transform(out vec4 r0, out vec4 r1, out vec4 r2) {")
    lines.append("    r0 = vec4(0.0); r1 = vec4(0.0); r2 = vec4(0.0);")
    lines.append("    float w;")
    for j in range(handles):
        lines.append(
            f"    w = in_dense{j // 4}.{'xyzw'[j % 4]}; "
            f"r0 += w * u_rows[{3 * j}]; r1 += w * u_rows[{3 * j + 1}]; r2 += w * u_rows[{3 * j + 2}];"
        )
    lines.append("}")
    return "\n".join(lines)


def skin_chunk(slots: int, spill: bool) -> str:
    """GLSL of blend_transform(): the sum of w * A_j over the vertex's pairs, `slots` of them
    from attributes in_weight<g> (vec4) and in_handles<h> (uvec4, two 16-bit indices per uint),
    unrolled, then the spilled ones from the texture when spill is True."""
    lines = [SKIN_COMMON]
    lines += [f"in vec4 in_weight{g};" for g in range(slots // 4)]
    lines += [f"in uvec4 in_handles{h};" for h in range(slots // 8)]  # slots: a multiple of 8
    if spill:
        lines.append(SKIN_SPILL)
    lines.append("void blend_transform(out vec4 r0, out vec4 r1, out vec4 r2) {")
    lines.append("    r0 = vec4(0.0); r1 = vec4(0.0); r2 = vec4(0.0);")
    lines.append("    float w; int j;")
    for slot in range(slots):
        packed = f"in_handles{slot // 8}.{'xyzw'[(slot % 8) // 2]}"
        handle = f"{packed} & 0xFFFFu" if slot % 2 == 0 else f"{packed} >> 16"
        lines.append(
            f"    w = in_weight{slot // 4}.{'xyzw'[slot % 4]}; j = 3 * int({handle}); "
            "r0 += w * u_rows[j]; r1 += w * u_rows[j + 1]; r2 += w * u_rows[j + 2];"
        )
    if spill:
        lines.append("    add_spilled(r0, r1, r2);")
    lines.append("}")
    return "\n".join(lines)


# Skinning pass: every vertex once, captured by transform feedback into one buffer of
# (position, normal, colour) triples that the mesh pass then draws. Shading each vertex once
# matters on llvmpipe, whose indexed draws may shade a vertex several times (about 3x slower
# here). With VERTEX_LIGHTING the pass also lights the vertex (linear RGB; else the colour is 0).
SKIN_VERTEX = """
in vec3 in_position;
in vec3 in_normal;
out vec3 out_position;
out vec3 out_normal;
out vec3 out_color;
void main() {
    vec4 r0, r1, r2;
    blend_transform(r0, r1, r2);
    out_position = apply_affine(r0, r1, r2, in_position);
    out_normal = transform_normal(r0, r1, r2, in_normal);
#if VERTEX_LIGHTING
    out_color = shade(normalize(out_normal));
#else
    out_color = vec3(0.0);
#endif
}
"""

# Mesh pass, lit per pixel: skinned positions and normals (from the skinning pass). Only the
# normal is interpolated (llvmpipe's triangle setup cost grows with every interpolated float).
MESH_VERTEX = """
uniform mat4 u_view_proj;
in vec3 in_position;
in vec3 in_normal;
out vec3 v_normal;
void main() {
    v_normal = in_normal;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
"""

# Mesh pass, lit per vertex (closed meshes, back faces culled): the skinning pass's colours,
# interpolated; the fragment only encodes them for display.
MESH_LIT_VERTEX = """
uniform mat4 u_view_proj;
in vec3 in_position;
in vec3 in_color;
out vec3 v_color;
void main() {
    v_color = in_color;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
"""

MESH_LIT_FRAGMENT = """
in vec3 v_color;
out vec4 f_color;
void main() { f_color = vec4(to_display(v_color), 1.0); }
"""

# Mesh pass for CPU skinning (positions only): face normals from screen derivatives.
MESH_CPU_VERTEX = """
uniform mat4 u_view_proj;
in vec3 in_position;
out vec3 v_world;
void main() {
    v_world = in_position;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
"""

LIGHTING = """
uniform vec3 u_up;
uniform vec3 u_key_dir;     // toward the light, world space
uniform vec3 u_fill_dir;
uniform vec3 u_sky;
uniform vec3 u_ground_bounce;
uniform vec3 u_albedo;
uniform vec3 u_view_dir;    // from the scene toward the camera (the camera's, constant)

// Display encoding with gamma 2 (sqrt): close to sRGB and much cheaper than pow on llvmpipe.
vec3 to_display(vec3 linear) { return sqrt(clamp(linear, 0.0, 1.0)); }

// Linear RGB of the character's surface with unit normal n: sky/ground ambient, key and fill
// lights, a key highlight and a cool rim.
vec3 shade(vec3 n) {
    vec3 v = u_view_dir;
    float up = dot(n, u_up);
    vec3 ambient = mix(u_ground_bounce, u_sky, 0.5 + 0.5 * up);
    float key = max(dot(n, u_key_dir), 0.0);
    float fill = max(dot(n, u_fill_dir), 0.0);
    float spec = max(dot(n, normalize(u_key_dir + v)), 0.0);
    spec *= spec; spec *= spec; spec *= spec; spec *= spec; spec *= spec * key;  // ^32, no pow
    float rim = 1.0 - max(dot(n, v), 0.0);
    rim = rim * rim * rim;
    vec3 light = ambient * 0.55 + key * vec3(1.0, 0.94, 0.86) * 0.95 + fill * vec3(0.55, 0.65, 0.85) * 0.35;
    return u_albedo * light + spec * 0.18 + rim * vec3(0.6, 0.7, 0.9) * 0.35;
}
"""

MESH_FRAGMENT = """
#if FACE_NORMALS
in vec3 v_world;
#else
in vec3 v_normal;
#endif
out vec4 f_color;
void main() {
#if FACE_NORMALS
    vec3 n = normalize(cross(dFdx(v_world), dFdy(v_world)));
    if (dot(n, u_view_dir) < 0.0) n = -n;
#else
    vec3 n = normalize(v_normal);
    if (!gl_FrontFacing) n = -n;
#endif
    f_color = vec4(to_display(shade(n)), 1.0);
}
"""

GROUND_VERTEX = """
uniform mat4 u_view_proj;
in vec3 in_position;
out vec3 v_world;
void main() {
    v_world = in_position;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
"""

# Occlusion of the ground by the shadow spheres, rendered into a small texture over the ground
# square (one fragment per texel: cheap), then sampled bilinearly by GROUND_FRAGMENT.
OCCLUSION_VERTEX = """
uniform vec3 u_shadow_center;     // middle of the shadow square (under the character)
uniform vec3 u_shadow_a;          // ground axes scaled by the shadow square's half size
uniform vec3 u_shadow_b;
in vec2 in_corner;                // -1..1
out vec3 v_world;
void main() {
    v_world = u_shadow_center + in_corner.x * u_shadow_a + in_corner.y * u_shadow_b;
    gl_Position = vec4(in_corner, 0.0, 1.0);
}
"""

OCCLUSION_FRAGMENT = """
uniform vec4 u_spheres[SPHERES];  // xyz: center, w: radius
uniform vec3 u_up;
in vec3 v_world;
out vec4 f_visible;
void main() {
    float visible = 1.0;
    for (int s = 0; s < SPHERES; ++s) {
        vec3 d = u_spheres[s].xyz - v_world;
        float r2 = u_spheres[s].w * u_spheres[s].w;
        float h = max(dot(d, u_up), 0.0);
        // Cosine-weighted solid angle of a sphere, (r / dist)^2 cos(theta), with dist^2 softened
        // to dist^2 + r^2 so that overlapping spheres blend into one smooth shadow.
        float s2 = dot(d, d) + r2;
        visible *= 1.0 - min(3.0 * r2 * h * inversesqrt(s2) / s2, 0.9);
    }
    f_visible = vec4(visible);
}
"""

# The ground disc, fading into the background, darkened by the occlusion texture (SHADOWED 1)
# or without it (SHADOWED 0: the backdrop drawn once per camera).
GROUND_FRAGMENT = """
#if SHADOWED
uniform sampler2D u_visibility;
uniform vec3 u_shadow_center;
uniform vec3 u_shadow_a;          // ground axes scaled by the shadow square's half size
uniform vec3 u_shadow_b;
uniform float u_shadow_half;      // half size of the shadow square (outside: no occlusion)
#endif
uniform vec3 u_center;            // middle of the ground disc
uniform float u_extent;           // radius of the ground disc
uniform vec3 u_ground_color;
uniform vec3 u_background;       // display-space RGB, like the clear color
in vec3 v_world;
out vec4 f_color;
void main() {
    vec3 rel = v_world - u_center;
#if SHADOWED
    vec3 shadow_rel = v_world - u_shadow_center;
    vec2 uv = 0.5 + 0.5 * vec2(dot(shadow_rel, u_shadow_a), dot(shadow_rel, u_shadow_b))
                    / (u_shadow_half * u_shadow_half);
    // Faded out towards the square's border (a round fade: no corner shows), where the shadow
    // meets the backdrop's bare ground.
    float occlusion = (1.0 - texture(u_visibility, uv).r) * (1.0 - smoothstep(0.5, 1.0, length(2.0 * uv - 1.0)));
#else
    float occlusion = 0.0;
#endif
    vec3 lit = u_ground_color * mix(u_ground_bounce, u_sky, 0.85) * (1.0 - 0.85 * occlusion);
    float fade = 1.0 - smoothstep(0.45 * u_extent, u_extent, length(rel));
    f_color = vec4(mix(u_background, to_display(lit), fade), 1.0);
}
"""

# The shadow square on the ground (where the occlusion texture lies), following the character.
SHADOW_SQUARE_VERTEX = """
uniform mat4 u_view_proj;
uniform vec3 u_shadow_center;
uniform vec3 u_shadow_a;
uniform vec3 u_shadow_b;
in vec2 in_corner;                // -1..1
out vec3 v_world;
void main() {
    v_world = u_shadow_center + in_corner.x * u_shadow_a + in_corner.y * u_shadow_b;
    gl_Position = u_view_proj * vec4(v_world, 1.0);
}
"""

BONE_VERTEX = """
uniform mat4 u_view_proj;
uniform vec2 u_viewport;   // width, height [px]
uniform float u_width_px;
in vec2 in_corner;         // x: 0 at head, 1 at tail; y: -1..1 across
in vec3 in_head;
in vec3 in_tail;
in vec3 in_color;
out vec3 v_color;
void main() {
    vec4 a = u_view_proj * vec4(in_head, 1.0);
    vec4 b = u_view_proj * vec4(in_tail, 1.0);
    vec2 sa = a.xy / a.w * 0.5 * u_viewport, sb = b.xy / b.w * 0.5 * u_viewport;
    vec2 dir = sb - sa;
    dir = length(dir) > 1e-6 ? normalize(dir) : vec2(1.0, 0.0);
    vec2 across = vec2(-dir.y, dir.x) * in_corner.y * u_width_px;
    vec4 p = mix(a, b, in_corner.x);
    p.xy += across * 2.0 / u_viewport * p.w;
    gl_Position = p;
    v_color = in_color * (0.8 + 0.2 * in_corner.y);
}
"""

BONE_FRAGMENT = """
in vec3 v_color;
out vec4 f_color;
void main() { f_color = vec4(v_color, 1.0); }
"""


def source(*chunks: str, **defines) -> str:
    """GLSL 330 source: #define NAME value for each keyword, then the chunks in order."""
    lines = ["#version 330 core"] + [f"#define {name} {value}" for name, value in defines.items()]
    return "\n".join(lines + list(chunks))

# Fast approximate antialiasing (after Lottes' FXAA idea, reduced to one edge-direction blur):
# a cheaper alternative to MSAA on llvmpipe. Full-screen triangle over the aliased image.
FXAA_VERTEX = """
out vec2 v_uv;
void main() {
    vec2 corner = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = corner;
    gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}
"""

# The 3x3 neighbourhood's corners by unfiltered fetches (cheaper than filtered ones), their luma
# range, and whether the pixel sits on an edge.
FXAA_NEIGHBOURS = """
uniform sampler2D u_image;
uniform vec2 u_texel;            // 1 / (width, height)
in vec2 v_uv;
out vec4 f_color;
const vec3 LUMA = vec3(0.299, 0.587, 0.114);
vec3 center; float nw, ne, sw, se, lo, hi;
bool on_edge() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 last = textureSize(u_image, 0) - 1;
    center = texelFetch(u_image, p, 0).rgb;
    nw = dot(texelFetch(u_image, clamp(p + ivec2(-1, -1), ivec2(0), last), 0).rgb, LUMA);
    ne = dot(texelFetch(u_image, clamp(p + ivec2(1, -1), ivec2(0), last), 0).rgb, LUMA);
    sw = dot(texelFetch(u_image, clamp(p + ivec2(-1, 1), ivec2(0), last), 0).rgb, LUMA);
    se = dot(texelFetch(u_image, clamp(p + ivec2(1, 1), ivec2(0), last), 0).rgb, LUMA);
    float m = dot(center, LUMA);
    lo = min(m, min(min(nw, ne), min(sw, se)));
    hi = max(m, max(max(nw, ne), max(sw, se)));
    return hi - lo >= max(0.05, hi * 0.125);
}
vec3 blur_along_edge() {
    // The direction perpendicular to the luma gradient.
    vec2 dir = vec2(-((nw + ne) - (sw + se)), (nw + sw) - (ne + se));
    float reduce = max((nw + ne + sw + se) * (0.25 / 8.0), 1.0 / 128.0);
    dir = clamp(dir / (min(abs(dir.x), abs(dir.y)) + reduce), -8.0, 8.0) * u_texel;
    vec3 near = 0.5 * (texture(u_image, v_uv - dir / 6.0).rgb + texture(u_image, v_uv + dir / 6.0).rgb);
    vec3 far = 0.5 * near + 0.25 * (texture(u_image, v_uv - dir * 0.5).rgb + texture(u_image, v_uv + dir * 0.5).rgb);
    float far_luma = dot(far, LUMA);
    return (far_luma < lo || far_luma > hi) ? near : far;
}
"""

# One pass: every pixel tests for an edge and blurs there (llvmpipe shades both branches).
FXAA_FRAGMENT = FXAA_NEIGHBOURS + """
void main() {
    if (!on_edge()) {   // no edge here: keep the pixel
        f_color = vec4(center, 1.0);
        return;
    }
    f_color = vec4(blur_along_edge(), 1.0);
}
"""

# Two passes, for llvmpipe: the first marks edge pixels in the depth buffer (depth 0, else 1;
# colour writes off), the second blurs with the depth test passing only there, so that the
# rasterizer's early depth test skips the blur everywhere else (half the cost of one pass).
FXAA_MARK_FRAGMENT = FXAA_NEIGHBOURS + """
void main() { gl_FragDepth = on_edge() ? 0.0 : 1.0; f_color = vec4(center, 1.0); }
"""
FXAA_BLUR_FRAGMENT = FXAA_NEIGHBOURS + """
void main() { on_edge(); f_color = vec4(blur_along_edge(), 1.0); }
"""
