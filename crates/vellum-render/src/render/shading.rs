//! The uniforms every renderer's shaders read, mirroring `glsl/render/render.glsl`'s
//! `SliceUniforms` and the bindings of `glsl/render/shade.glsl`, which the slicer's fragment
//! shaders and the ray caster share: one struct, one binding list, one layout test.

use crate::classify::modulation::Modulation;
use vellum_gpu::BindingKind;

/// Uniforms of the slice shaders (GLSL twin: `SliceUniforms` in render.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SliceUniforms {
    /// Box frame → clip space (`FrameCamera::view_proj`), column-major.
    pub view_proj: [[f32; 4]; 4],
    /// xyz: half size of the volume's box in world units (longest edge 1), centred at 0; w: one
    /// world unit in the volume's units (its longest edge, in millimetres for medical data).
    pub(crate) half_extent: [f32; 4],
    /// xyz: the eye in the box frame; w unused.
    pub eye: [f32; 4],
    /// xyz: unit direction from the eye into the scene, box frame; w 1 for an orthographic camera.
    pub view_dir: [f32; 4],
    /// xyz: unit direction towards the light (a headlight, −view_dir); w the specular exponent.
    pub light: [f32; 4],
    /// Ambient, diffuse and specular coefficients; w the opacity correction, plane spacing / voxel.
    pub(crate) material: [f32; 4],
    /// lo, hi and mode of `Focus::normalised` (normalised intensity); w 1 when an occlusion TF
    /// classifies.
    pub focus: [f32; 4],
    /// x colour mode (0 off, 1 raw, 2 abs), y opacity on, z stipple on, w levels (1 focus,
    /// 2 context, 3 both; 0 when nothing is modulated).
    pub(crate) mod_flags: [i32; 4],
    /// x γ, y base colour (0 ambient, 1 Phong).
    pub(crate) mod_color: [f32; 4],
    /// t_l, t_h, k_l, k_h (eq. 5).
    pub(crate) mod_opacity: [f32; 4],
    /// x t, y f (eq. 6).
    pub(crate) mod_stipple: [f32; 4],
    /// x stipple seed.
    pub(crate) mod_seed: [u32; 4],
    /// rgb: eq. 6's white stipple colour; w 1.
    pub stipple_white: [f32; 4],
    /// rgb: eq. 6's black stipple colour; w 1.
    pub stipple_black: [f32; 4],
    /// Volume size in voxels (xyz), for the stipple grid and the gradients made at each sample.
    pub(crate) volume_dims: [f32; 4],
    /// The ray caster's region in texture coordinates, samples in [lo, hi) only (`region_hi[3]`
    /// = 1 when set): one rank's box of an MPI job.
    pub(crate) region_lo: [f32; 4],
    /// xyz: the region's upper corner (exclusive); w 1 when a region is set, else 0.
    pub(crate) region_hi: [f32; 4],
}

impl SliceUniforms {
    /// Writes the modulation fields (all off when `m` is inactive).
    pub(crate) fn set_modulation(&mut self, m: &Modulation, dims: [usize; 3]) {
        use crate::classify::modulation::{ApplyTo, ColorMode, ModulateLighting};
        let levels = match m.apply_to {
            ApplyTo::Focus => 1,
            ApplyTo::Context => 2,
            ApplyTo::Both => 3,
        };
        self.mod_flags = [
            match m.color.map(|c| c.mode) {
                None => 0,
                Some(ColorMode::Raw) => 1,
                Some(ColorMode::Abs) => 2,
            },
            m.opacity.is_some() as i32,
            m.stipple.is_some() as i32,
            if m.is_active() { levels } else { 0 },
        ];
        self.mod_color = [
            m.color.map_or(0.0, |c| c.gamma),
            (m.lighting == ModulateLighting::Phong) as i32 as f32,
            0.0,
            0.0,
        ];
        if let Some(o) = &m.opacity {
            self.mod_opacity = [o.t_low, o.t_high, o.k_low, o.k_high];
        }
        if let Some(st) = &m.stipple {
            self.mod_stipple = [st.t, st.f, 0.0, 0.0];
            self.mod_seed = [st.seed, 0, 0, 0];
            self.stipple_white = [st.white[0], st.white[1], st.white[2], 1.0];
            self.stipple_black = [st.black[0], st.black[1], st.black[2], 1.0];
        }
        self.volume_dims = [dims[0] as f32, dims[1] as f32, dims[2] as f32, 0.0];
    }
}

/// Uniforms; intensity, gradient, TF, occlusion, OTF, ΔD; max |ΔD| (`shade.glsl`, which the ray
/// caster shares).
pub(crate) const SHADE_BINDINGS: [BindingKind; 8] = [
    BindingKind::UniformBuffer,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
];

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    #[test]
    fn uniforms_match_glsl() {
        assert_glsl_layout!(
            SliceUniforms,
            "render.glsl",
            "SliceUniforms",
            [
                view_proj,
                half_extent,
                eye,
                view_dir,
                light,
                material,
                focus,
                mod_flags,
                mod_color,
                mod_opacity,
                mod_stipple,
                mod_seed,
                stipple_white,
                stipple_black,
                volume_dims,
                region_lo,
                region_hi
            ]
        );
    }
}
