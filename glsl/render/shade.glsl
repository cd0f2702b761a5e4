// The slicer's glue between its bindings and the shared classification and shading functions
// (glsl/common/classify.glsl, shading.glsl): one-pass, focus and context fragment shaders include
// it, and so does the ray caster (with RAYCAST defined), so all levels and both renderers see
// exactly the same samples. Textures have one level and are read with textureLod(.., 0): compute
// shaders have no derivatives for an implicit level.
#include "render.glsl"
#include "classify.glsl"
#include "shading.glsl"

layout(set = 0, binding = 0) uniform Uniforms { SliceUniforms u; };
layout(set = 0, binding = 1) uniform sampler3D volume;      // normalised intensity
layout(set = 0, binding = 2) uniform sampler3D gradient;    // xyz gradient (world), w length
layout(set = 0, binding = 3) uniform sampler2D transfer;    // 1D transfer function, 256 x 1
layout(set = 0, binding = 4) uniform sampler3D occlusion;   // ambient occlusion O (OTF only)
layout(set = 0, binding = 5) uniform sampler2D occlusion_tf; // 2D table over (s, O) (OTF only)
layout(set = 0, binding = 6) uniform sampler3D importance;   // ΔD, normalised units (modulation only)
layout(set = 0, binding = 7) readonly buffer ImportanceMax { uint max_abs_bits; } importance_max;

#ifdef RAYCAST
// The ray caster sets the sample's position before each call: `tex` in the volume, `ptex` where
// its intensity and gradient are read (the same, or the sample's place in the brick pool).
vec3 tex;
vec3 ptex;
vec3 world;
// Bricked (V_BRICKED): the pool's size in texels and its reciprocal, a voxel's step where `ptex`
// reads (raycast.comp's read_header sets them), and the voxels per unit of `tex` of the level
// `ptex` reads, set with each sample's place (its `locate`), for `sobel_at`.
vec3 pool_size, inv_pool;
vec3 p_level_dims;
// Level 0's voxel over the wanted level's (1 in core): opacity is corrected per voxel of the
// level a bricked sample wants, so a coarse level looks as that level rendered in core. A sample
// whose brick is missing reads a coarser level in its stead, at the opacity of the level it wants.
float level_ratio = 1.0;
// The ray caster is specialised per frame set-up (render/raycast.rs, `Variant`): a CPU rasteriser
// runs both sides of every branch its lanes diverge on, and cannot skip one whose condition is a
// uniform, so features a frame does not use are compiled out instead of branched around. Each bit
// enables code that still checks its uniform, so a set bit is never wrong, only slower.
layout(constant_id = 0) const uint VARIANT = 0xffffffffu;
const bool V_TWO_LEVEL = (VARIANT & 1u) != 0u;
const bool V_SKIP_EMPTY = (VARIANT & 2u) != 0u;
const bool V_JITTER = (VARIANT & 4u) != 0u;
const bool V_REFINE_ISO = (VARIANT & 8u) != 0u;
const bool V_WORLD_STEPS = (VARIANT & 16u) != 0u;
const bool V_OTF = (VARIANT & 32u) != 0u;
const bool V_MOD_OPACITY = (VARIANT & 64u) != 0u;
const bool V_MOD_SHADE = (VARIANT & 128u) != 0u;
const bool V_BRICKED = (VARIANT & 256u) != 0u;
const bool V_BRICK_REUSE = (VARIANT & 512u) != 0u;
const bool V_BRICK_SPAN = (VARIANT & 1024u) != 0u;
const bool V_LABELS = (VARIANT & 2048u) != 0u;
const bool V_MIX_OVER = (VARIANT & 4096u) != 0u;
const bool V_MIX_ADD = (VARIANT & 8192u) != 0u;
const bool V_MIX_MAX = (VARIANT & 16384u) != 0u;
const bool V_CHANNELS = V_MIX_OVER || V_MIX_ADD || V_MIX_MAX;
const bool V_WALK_BATCH = (VARIANT & 32768u) != 0u;
// Bits 16-18 hold the channel count (below). A label volume with a hidden segment: samples whose
// filtered intensity blends one of its voxels add nothing (raycast.comp's `screened`).
const bool V_LABELS_SCREEN = (VARIANT & 524288u) != 0u;
// Bricked, by the level-of-detail rule: samples that want a coarser level than the planes' step
// over planes (raycast.comp's `steps_of`, from the planes' level in the page table's header).
const bool V_LOD_STEPS = (VARIANT & 1048576u) != 0u;
// With V_LOD_STEPS, in a frame drawn around missing bricks: a sample a coarser level stands in
// for is that level's voxel long (raycast.comp's `widen_step`). Only such frames take it: a CPU
// device pays for the code at every sample, needed or not.
const bool V_WIDEN = (VARIANT & 2097152u) != 0u;
// With BRICKED and skipping: a ray passes the bricks and sub-blocks known to hold nothing it
// needs in front of it in a loop that only looks them up, before its walk (raycast.comp's
// past_empty; `Paged::trim`).
const bool V_TRIM = (VARIANT & 4194304u) != 0u;
// No gradient texture: in core, a volume whose intensity fits the GPU budget and whose gradients
// would not; bricked, always (the pool holds intensity alone). Each shaded sample's Sobel
// gradient is made from 26 intensity fetches (`sobel_at`); `gradient` is a stand-in, never read.
const bool V_GRADIENT_AT_SAMPLE = (VARIANT & 8388608u) != 0u;
// Channels of a store mixed in one ray (classify/channels.rs): up to eight, component k of
// `channels` (k < 4) or k - 4 of `channels_hi` over channel k's own range, with its transfer
// function in row k of `channel_tf`. Frames without channels bind stand-ins and never read them;
// frames of four or fewer bind `channels` again as `channels_hi` and never read it.
layout(set = 0, binding = 19) uniform sampler3D channels;
layout(set = 0, binding = 20) uniform sampler2D channel_tf;
// Per channel, 256 opacity bounds (float bits) of its transfer function's texels.
layout(set = 0, binding = 21) readonly buffer ChannelBounds { uint channel_bounds[]; };
layout(set = 0, binding = 22) uniform sampler3D channels_hi;
const int MAX_CHANNELS = 8;
// How many channels are mixed: bits 16-18 of VARIANT hold the count less one. A specialisation
// constant, so that every loop over the channels unrolls (a CPU device keeps an array indexed at
// run time in memory) and a frame of four or fewer never reads `channels_hi`.
const int CHANNEL_COUNT = int((VARIANT >> 16u) & 7u) + 1;

// The channels' values at the sample being classified, 0-3 and 4-7 (the ray caster fetches them
// once per sample, in its walk).
vec4 channel_sample;
vec4 channel_sample_hi;

// Fetches every channel's value at texture coordinate `at` into `channel_sample(_hi)`: one fetch
// for up to four channels, two for more.
void fetch_channels(vec3 at) {
    channel_sample = textureLod(channels, at, 0.0);
    if (CHANNEL_COUNT > 4) {
        channel_sample_hi = textureLod(channels_hi, at, 0.0);
    }
}

// Channel k's value at the fetched sample.
float channel_value(int k) {
    return k < 4 ? channel_sample[k] : channel_sample_hi[k - 4];
}

// Whether some channel at the fetched sample may give it an opacity of `a_min` or more (a bound
// from the texels linear filtering blends, so a sample it passes over adds nothing). `over`
// mixes n channels, whose opacities together stay below n times the largest.
bool channels_may_show(float a_min) {
    int n = CHANNEL_COUNT;
    float bound = 0.0;
    for (int k = 0; k < n; k++) {
        int i = tf_pair(channel_value(k));
        bound = max(bound, uintBitsToFloat(channel_bounds[256 * k + i]));
    }
    return bound * float(n) >= a_min;
}

// Channel k's class of value v (straight colour, opacity).
vec4 channel_class(int k, float v) {
    return textureLod(channel_tf, vec2(tf_coord(v), (float(k) + 0.5) / float(CHANNEL_COUNT)), 0.0);
}

// The channels' classes of the fetched sample mixed by `over` into one sample's straight colour
// and opacity: composited with the first channel on top. (`add` and `max` are projections of
// their own, raycast.comp's `channel_projection`.)
vec4 mixed_channels() {
    int n = CHANNEL_COUNT;
    vec4 acc = vec4(0.0);
    for (int k = 0; k < n; k++) {
        vec4 t = channel_class(k, channel_value(k));
        acc += (1.0 - acc.a) * vec4(t.rgb * t.a, t.a);
    }
    float a = min(acc.a, 1.0);
    return a > 0.0 ? vec4(min(acc.rgb / a, vec3(1.0)), a) : vec4(0.0);
}
#else
const bool V_OTF = true;
const bool V_MOD_OPACITY = true;
const bool V_MOD_SHADE = true;
layout(location = 0) in vec3 tex;
layout(location = 1) in vec3 world;
#define ptex tex
const float level_ratio = 1.0;
#endif

bool sample_in_focus(float s) {
    return in_focus(s, u.focus);
}

// The normalised intensity of this fragment's sample. Shaders classify it first and discard
// before paying for the transfer function, the gradient and the lighting.
float sample_intensity() {
    return textureLod(volume, ptex, 0.0).r;
}

// Whether importance modulation applies to a sample of the focus level (or of the context).
bool modulated(bool focus) {
    return ((focus ? 1 : 2) & u.mod_flags.w) != 0;
}

// n = |ΔD| / max |ΔD| in [0, 1].
float importance_n(float delta_d) {
    float m = uintBitsToFloat(importance_max.max_abs_bits);
    return m > 0.0 ? min(abs(delta_d) / m, 1.0) : 0.0;
}

// Colour (straight) and opacity of intensity s, the opacity modulated (eq. 5) and then corrected
// for the slice spacing (material.w = spacing / voxel). focus.w = 1: the occlusion transfer
// function replaces the 1D one.
vec4 classify(float s, bool focus) {
    vec4 rgba;
    if (V_OTF && u.focus.w > 0.5) {
        rgba = textureLod(occlusion_tf, occlusion_tf_coord(s, textureLod(occlusion, tex, 0.0).r), 0.0);
    } else {
#ifdef RAYCAST
        rgba = V_CHANNELS ? mixed_channels() : textureLod(transfer, vec2(tf_coord(s), 0.5), 0.0);
#else
        rgba = textureLod(transfer, vec2(tf_coord(s), 0.5), 0.0);
#endif
    }
    if (V_MOD_OPACITY && u.mod_flags.y != 0 && modulated(focus)) {
        rgba.a = modulate_opacity(rgba.a, importance_n(textureLod(importance, tex, 0.0).r), u.mod_opacity);
    }
    return classify_sample(rgba, u.material.w * level_ratio, focus, u.focus);
}

#ifdef RAYCAST
// The gradient a volume's stored gradients interpolate to at texture coordinate `at`, made there
// from `volume` (V_GRADIENT_AT_SAMPLE): the 3D Sobel operator of `sobel_normals.comp` applied to
// the trilinear reconstruction, as the sum of its 26 weights times the intensity filtered at
// whole voxels from `at`. Shifting the reconstruction by whole voxels commutes with it, so this
// is the trilinear interpolation of the Sobel gradients of the eight voxels around `at`: what the
// texture of stored ones gives (up to its half floats; the borders, which clamp, differ in their
// outer half voxel). Eight fetches at half voxels would be cheaper, but they reconstruct a
// different gradient between the voxels' centres: frames differed by 1.1/255 on average on the CT
// head and 1.4/255 on the chest. Only shaded samples pay for it, once each.
// Bricked, the fetches stay in the sample's slot: its apron is two voxels deep.
vec4 sobel_at(vec3 at) {
    vec3 dims = V_BRICKED ? p_level_dims : u.volume_dims.xyz;
    vec3 h = V_BRICKED ? inv_pool : 1.0 / u.volume_dims.xyz;
    vec3 g = vec3(0.0);
    for (int k = 0; k < 27; ++k) {
        ivec3 o = ivec3(k % 3, (k / 3) % 3, k / 9) - 1;
        if (k == 13) {
            continue;
        }
        // (1, 2, 1) across the axis, the difference along it.
        vec3 w = vec3(2 - abs(o));
        float v = textureLod(volume, at + vec3(o) * h, 0.0).r;
        g += v * vec3(o) * vec3(w.y * w.z, w.x * w.z, w.x * w.y);
    }
    // Over 32 and the spacing: the box's edges are the voxels times their spacing, in units of
    // its longest edge (half_extent.w, in the volume's units).
    g *= (1.0 / 32.0) * dims / (2.0 * u.half_extent.xyz * u.half_extent.w);
    return vec4(g, length(g));
}
#endif

// Phong (with specular) and diffuse-only colours of a sample of straight colour `rgb`, lit by the
// headlight, then modulated: a stippled sample takes one of the two stipple colours (eq. 6);
// otherwise colour modulation adds ΔD·γ or |ΔD|·γ (eq. 3, 4) to the unlit or the lit colour.
void shade(vec3 rgb, bool focus, out vec3 phong, out vec3 diffuse) {
    vec3 to_eye = u.view_dir.w > 0.5 ? -u.view_dir.xyz : normalize(u.eye.xyz - world);
#ifdef RAYCAST
    vec4 g = V_GRADIENT_AT_SAMPLE ? sobel_at(ptex) : textureLod(gradient, ptex, 0.0);
#else
    vec4 g = textureLod(gradient, ptex, 0.0);
#endif
    shade_phong(rgb, g, u.light.xyz, to_eye, u.material, u.light.w, phong, diffuse);
    if (!V_MOD_SHADE || !modulated(focus)) {
        return;
    }
    float delta_d = textureLod(importance, tex, 0.0).r;
    if (u.mod_flags.z != 0) {
        float r = stipple_random(tex * u.volume_dims.xyz, u.mod_seed.x);
        bool white = stipple_is_white(importance_n(delta_d), r, u.mod_stipple.x, u.mod_stipple.y);
        phong = white ? u.stipple_white.rgb : u.stipple_black.rgb;
        diffuse = phong;
    } else if (u.mod_flags.x != 0) {
        bool ambient = u.mod_color.y < 0.5;
        phong = modulate_color(ambient ? rgb : phong, delta_d, u.mod_flags.x, u.mod_color.x);
        diffuse = modulate_color(ambient ? rgb : diffuse, delta_d, u.mod_flags.x, u.mod_color.x);
    }
}
