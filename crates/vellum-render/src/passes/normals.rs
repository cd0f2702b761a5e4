//! Sobel normals on compute (SPEC TL1, pass `sobel_normals`): reads the normalised volume texture
//! and writes an RGBA16F 3D texture of gradients (xyz in world units, w = length), computed once per
//! volume and sampled by the slice renderer for Phong shading.

use crate::passes::volume_image::extent_of;
use std::sync::Arc;
use vellum_error::Result;
use vellum_gpu::Format;
use vellum_gpu::{
    Access, Bind, BindingKind, ComputePipeline, Context, Frame, Image, ImageDesc, PassTime, Sampler,
};
use vellum_volume::Volume;

/// Push constants of `render/sobel_normals.comp` (GLSL twin: `NormalsPush` in render.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct NormalsPush {
    /// Volume size in voxels.
    pub dims: [i32; 3],
    /// Bricks in the list of bricks whose gradients are computed (`VolumeTextures::active`), or
    /// -1: every voxel, in order. It also pads `inv_spacing` to byte 16, a vec4's std430
    /// alignment.
    pub listed: i32,
    /// 1 / voxel spacing along x, y, z, which scales the Sobel sums to world units; w unused.
    pub(crate) inv_spacing: [f32; 4],
}

/// Workgroup shape (NORMALS_LOCAL_* in render.glsl): 8 × 8 invocations, each a [`BLOCK`] of
/// columns. 2 × 2 columns an invocation read a quarter of the texels that one column did
/// (2.25 fetches a voxel, not 9) and took the pass from 440–550 to 300–320 ms on the bonsai
/// (256³) on lavapipe; a workgroup is one brick, which the listed bricks need.
pub(crate) const LOCAL_SIZE: [u32; 3] = [8, 8, 1];

/// Voxels along z of one invocation's columns (NORMALS_COLUMN in render.glsl).
pub(crate) const COLUMN: u32 = 16;

/// Columns of one invocation along x and y (NORMALS_BLOCK_* in render.glsl).
pub(crate) const BLOCK: [u32; 2] = [2, 2];

/// Voxels of one workgroup: its invocations' blocks of columns, each `COLUMN` deep.
const GROUP_VOXELS: [u32; 3] = [
    LOCAL_SIZE[0] * BLOCK[0],
    LOCAL_SIZE[1] * BLOCK[1],
    LOCAL_SIZE[2] * COLUMN,
];

/// Workgroups of one brick of `BRICK`³ voxels (one of [`GROUP_VOXELS`]).
const BRICK_GROUPS: u32 = (BRICK as u32 / GROUP_VOXELS[0])
    * (BRICK as u32 / GROUP_VOXELS[1])
    * (BRICK as u32 / GROUP_VOXELS[2]);

/// Workgroups along one dimension of a dispatch that every device takes.
const MAX_GROUP_ROWS: u32 = 65_535;

/// What a volume is drawn on: its own intensity range and `auto` line smoothing (the default),
/// or those given (a time point on its series' scale: the scene's `InputSpec::range` and
/// `InputSpec::line_smooth`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scale {
    /// The values the intensity scale spans.
    pub range: Option<[f64; 2]>,
    /// The `auto` line smoothing's radius.
    pub line_smooth: Option<u32>,
}

/// Where the shading's gradients of a volume in core come from.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum GradientSource {
    /// A texture of every voxel's Sobel gradient, made once (`sobel_normals`): 8 bytes a voxel
    /// beside the intensity's 2.
    Stored,
    /// None kept: the ray caster makes each shaded sample's Sobel gradient from 26 fetches of the
    /// intensity (`shade.glsl`'s `sobel_at`), the gradient the stored ones interpolate to. A
    /// volume whose intensity fits the GPU budget and whose stored gradients would not is drawn
    /// so, in core, rather than through the brick cache (`render::session`). Only the ray caster
    /// draws it.
    AtSample,
}

/// The gradients of a volume in core, as its [`GradientSource`] says.
pub enum Gradients {
    /// RGBA16F: the gradient in world units and its length, per voxel.
    Stored(Image),
    /// Made at each shaded sample from the intensity; no texture.
    AtSample,
}

impl Gradients {
    /// The texture of stored gradients, if any.
    pub fn image(&self) -> Option<&Image> {
        match self {
            Gradients::Stored(i) => Some(i),
            Gradients::AtSample => None,
        }
    }
}

/// The volume as the renderer sees it: a normalised R16_UNORM 3D texture and its gradients.
pub struct VolumeTextures {
    /// Intensity mapped from `[range[0], range[1]]` to `[0, 1]`.
    pub intensity: Image,
    /// The gradients: stored per voxel, or made at each sample.
    pub gradient: Gradients,
    /// Data values that map to 0 and 1.
    pub range: [f64; 2],
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f64; 3],
    /// Origin and directions of the volume (see `volume::geometry`).
    pub geometry: vellum_volume::geometry::Geometry,
    /// Ambient occlusion in [0, 1] for occlusion transfer functions (R32F, possibly coarser).
    pub occlusion: Option<Image>,
    /// Min and max of the normalised intensity per brick, for skipping bricks in a pass.
    pub bricks: Bricks,
    /// The bricks of `bricks` whose widened region holds more than one value, by index (x
    /// fastest), and how many, when `sobel_normals` runs on these only ([`Bricks::varying`]):
    /// every voxel of another brick has a zero gradient (its Sobel stencil lies in one value),
    /// which a clear writes.
    pub(crate) active: (vellum_gpu::Buffer, Option<usize>),
    /// ΔD of the normalised volume, for importance modulation.
    pub importance: Option<crate::passes::importance::ImportanceVolume>,
    /// A number no other `VolumeTextures` of this process has: what a view keeps for a volume
    /// (its smoothed copy) is keyed by it, so a new volume is never mistaken for the old one.
    pub id: u64,
    /// The smoothing radius `--line-smooth auto` gives this volume's object-space lines
    /// (`volume::lines::auto_smooth_radius`).
    pub(crate) auto_line_smooth: u32,
}

/// Edge of a brick in voxels.
pub(crate) const BRICK: usize = 16;

/// Per-brick range of the normalised intensity (0..=65535), widened by one voxel on every side:
/// a trilinear sample anywhere in a brick blends only voxels of that widened region, so it can
/// only take values within the brick's range.
#[derive(Clone, Debug)]
pub struct Bricks {
    /// Bricks along x, y, z.
    pub counts: [usize; 3],
    /// (min, max) per brick, x fastest.
    pub range: Vec<[u16; 2]>,
}

impl Bricks {
    /// The brick ranges of `texels` (normalised intensity, x fastest) of size `dims`.
    pub fn new(texels: &[u16], dims: [usize; 3]) -> Self {
        let (counts, range) = vellum_volume::bricks::widened_ranges(texels, dims, BRICK);
        Bricks { counts, range }
    }

    /// The indices of the bricks whose widened range holds more than one value (the Sobel
    /// stencil of every voxel of another lies in its one value, so its gradient is zero), when
    /// at least an eighth of the bricks are not: `sobel_normals` then runs on these only and a
    /// clear writes the rest. Else `None`, and the pass runs on every voxel in order: measured on
    /// the CT head (few bricks of one value), a list of all its bricks was 20 % slower, a brick
    /// of 16 slices being partly past its 113.
    pub(crate) fn varying(&self) -> Option<Vec<u32>> {
        let n = self.range.len() as u32;
        let varying: Vec<u32> = (0..n)
            .filter(|&i| self.range[i as usize][0] != self.range[i as usize][1])
            .collect();
        (varying.len() as u32 <= n - n / 8).then_some(varying)
    }

    /// Voxel bounds [lo, hi) of brick `b` along each axis, clamped to `dims`.
    pub(crate) fn voxel_bounds(&self, b: usize, dims: [usize; 3]) -> ([usize; 3], [usize; 3]) {
        let c = [
            b % self.counts[0],
            (b / self.counts[0]) % self.counts[1],
            b / (self.counts[0] * self.counts[1]),
        ];
        (
            std::array::from_fn(|a| c[a] * BRICK),
            std::array::from_fn(|a| ((c[a] + 1) * BRICK).min(dims[a])),
        )
    }
}

/// A number no other `VolumeTextures` of this process has (`VolumeTextures::id`).
pub(crate) fn next_volume_id() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl VolumeTextures {
    /// Allocates the textures of `v` (no GPU work yet) and a staging buffer holding its voxels
    /// normalised to R16; record the copy with `VolumeTextures::record_upload`.
    /// A whole volume, which a renderer may draw lines of: its `auto` line smoothing is measured
    /// here (a chunk of `VolumeTextures::new_in_range` is never drawn, and skips it).
    pub fn new(ctx: &Arc<Context>, v: &Volume) -> Result<(Self, vellum_gpu::Buffer)> {
        Self::new_over(ctx, v, Default::default(), GradientSource::Stored)
    }

    /// [`VolumeTextures::new`] on `scale` where it is given (a time point on its series'
    /// scale): over its range, else `v`'s own smallest and largest values, and with its line
    /// smoothing, else `v`'s measured; its gradients from `source`.
    pub fn new_over(
        ctx: &Arc<Context>,
        v: &Volume,
        scale: Scale,
        source: GradientSource,
    ) -> Result<(Self, vellum_gpu::Buffer)> {
        let range = scale.range.unwrap_or_else(|| v.normalised_range());
        let (mut textures, staging) = Self::new_in_range(ctx, v, range, source)?;
        textures.auto_line_smooth = scale
            .line_smooth
            .unwrap_or_else(|| vellum_volume::lines::auto_smooth_radius(v));
        Ok((textures, staging))
    }

    /// [`VolumeTextures::new`] with intensities normalised over `range`, not `v`'s own: a
    /// chunk of a larger grid takes the grid's range. Its `auto_line_smooth` is 0.
    pub(crate) fn new_in_range(
        ctx: &Arc<Context>,
        v: &Volume,
        range: [f64; 2],
        source: GradientSource,
    ) -> Result<(Self, vellum_gpu::Buffer)> {
        let stored = source == GradientSource::Stored;
        let extent = extent_of(ctx, v.dims, if stored { 2 + 8 } else { 2 }, 1)?;
        // R16_UNORM: intensity normalised to 65536 levels (more than 12-bit CT needs) at half the
        // bytes of float, sampled with trilinear filtering.
        let intensity = Image::new(
            ctx,
            "volume intensity",
            &ImageDesc::new_3d(Format::R16_UNORM, extent),
        )?;
        // RGBA16F: the gradient's xyz and length in half floats; shading needs no more, at half the
        // bytes of RGBA32F.
        let gradient = match source {
            GradientSource::Stored => Gradients::Stored(Image::new(
                ctx,
                "volume gradient",
                &ImageDesc::new_3d(Format::R16G16B16A16_SFLOAT, extent),
            )?),
            GradientSource::AtSample => Gradients::AtSample,
        };
        let (texels, range) = v.normalised_u16_in(range);
        let bricks = Bricks::new(&texels, v.dims);
        let list = bricks.varying();
        let active = (
            vellum_gpu::Buffer::storage_from_bytes(
                ctx,
                "varying bricks",
                bytemuck::cast_slice(list.as_deref().unwrap_or(&[])),
            )?,
            list.map(|l| l.len()),
        );
        let mut staging =
            vellum_gpu::transfer::staging_buffer(ctx, "volume staging", texels.len() * 2)?;
        staging.write(bytemuck::cast_slice(&texels))?;
        Ok((
            VolumeTextures {
                intensity,
                gradient,
                range,
                dims: v.dims,
                spacing: v.spacing,
                geometry: v.geometry,
                occlusion: None,
                bricks,
                active,
                importance: None,
                id: next_volume_id(),
                auto_line_smooth: 0,
            },
            staging,
        ))
    }

    /// The texture of stored gradients; a volume whose gradients are made at each sample has
    /// none, which is said.
    pub(crate) fn stored_gradient(&self) -> Result<&Image> {
        self.gradient.image().ok_or_else(|| {
            vellum_error::Error::Invalid(
                "this volume's gradients are made at each sample, not stored".into(),
            )
        })
    }

    /// Records pass `upload`: `staging` (from [`VolumeTextures::new`]) into the intensity texture.
    pub(crate) fn record_upload(
        &self,
        ctx: &Context,
        frame: &mut Frame,
        staging: &vellum_gpu::Buffer,
    ) {
        frame.profiler.pass(frame.cmd, "upload", |cmd| {
            vellum_gpu::transfer::record_upload(
                ctx,
                cmd,
                staging,
                &self.intensity,
                Access::ComputeSampled,
            )
        });
    }

    /// Uploads an occlusion volume (from `passes::occlusion`) for occlusion transfer functions.
    pub fn attach_occlusion(&mut self, ctx: &Arc<Context>, occlusion: &Volume) -> Result<()> {
        let vellum_volume::VoxelData::F32(o) = &occlusion.data else {
            return Err(vellum_error::Error::Invalid(
                "an occlusion volume must be float".into(),
            ));
        };
        let extent = extent_of(ctx, occlusion.dims, 4, 1)?;
        // R32F: the occlusion volume arrives from the host as f32 in [0, 1] and is kept so.
        let image = Image::new(
            ctx,
            "occlusion texture",
            &ImageDesc::new_3d(Format::R32_SFLOAT, extent),
        )?;
        vellum_gpu::transfer::upload(
            ctx,
            &image,
            bytemuck::cast_slice(o),
            Access::FragmentSampled,
        )?;
        self.occlusion = Some(image);
        Ok(())
    }
}

/// A chunk staged for [`Normals::run`] by `Normals::stage`.
pub struct StagedNormals {
    textures: VolumeTextures,
    upload: vellum_gpu::Buffer,
    readback: vellum_gpu::Buffer,
}

impl StagedNormals {
    /// The gradients [`Normals::run`] read back, as floats (host work, beside other threads').
    pub fn gradients(&self) -> Result<Vec<[f32; 4]>> {
        let bytes = self.readback.mapped().ok_or_else(|| {
            vellum_error::Error::Invalid("the readback buffer is not host-visible".into())
        })?;
        Ok(bytes
            .chunks_exact(8)
            .map(|t| {
                std::array::from_fn(|c| half::f16::from_le_bytes([t[2 * c], t[2 * c + 1]]).to_f32())
            })
            .collect())
    }

    /// The gradients [`Normals::run`] read back over the box `lo .. lo + size` of the staged
    /// volume of `dims`: its four channels (x, y, z and length), each as floats, x fastest.
    /// Row by row from the readback, each row's half floats converted at once, without the whole
    /// box's floats first (host work, beside other threads'; a chunked pass keeps only its
    /// chunk of the box it reads with a halo).
    pub fn channels_in(
        &self,
        dims: [usize; 3],
        (lo, size): ([usize; 3], [usize; 3]),
    ) -> Result<[Vec<f32>; 4]> {
        use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
        let bytes = self.readback.mapped().ok_or_else(|| {
            vellum_error::Error::Invalid("the readback buffer is not host-visible".into())
        })?;
        let halves: &[u16] = bytemuck::try_cast_slice(bytes).map_err(|e| {
            vellum_error::Error::Invalid(format!("readback memory does not hold halves: {e}"))
        })?;
        if halves.len() != 4 * dims.iter().product::<usize>()
            || (0..3).any(|a| lo[a] + size[a] > dims[a])
        {
            return Err(vellum_error::Error::Invalid(format!(
                "a box at {lo:?} of {size:?} does not lie in the {dims:?} gradients read back"
            )));
        }
        let n = size.iter().product::<usize>();
        let mut out: [Vec<f32>; 4] = std::array::from_fn(|_| Vec::with_capacity(n));
        let mut row = vec![0f32; 4 * size[0]];
        for z in lo[2]..lo[2] + size[2] {
            for y in lo[1]..lo[1] + size[1] {
                let at = 4 * (lo[0] + dims[0] * (y + dims[1] * z));
                let texels = &halves[at..at + 4 * size[0]];
                texels
                    .reinterpret_cast::<half::f16>()
                    .convert_to_f32_slice(&mut row);
                for (c, channel) in out.iter_mut().enumerate() {
                    channel.extend(row.iter().skip(c).step_by(4));
                }
            }
        }
        Ok(out)
    }
}

/// The `sobel_normals` pipelines: over every voxel, and over listed bricks (built when a volume
/// first needs it).
pub struct Normals {
    ctx: Arc<Context>,
    pipeline: ComputePipeline,
    listed: std::sync::OnceLock<ComputePipeline>,
    nearest: Sampler,
}

/// `sobel_normals.comp`'s bindings: the intensity, the gradient, the listed bricks.
const NORMALS_BINDINGS: [BindingKind; 3] = [
    BindingKind::SampledImage,
    BindingKind::StorageImage,
    BindingKind::StorageBuffer,
];

impl Normals {
    /// Builds the pipeline.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        let pipeline = Self::build(ctx, false)?;
        Ok(Normals {
            ctx: ctx.clone(),
            pipeline,
            listed: std::sync::OnceLock::new(),
            nearest: Sampler::new(ctx, false)?,
        })
    }

    /// The pipeline over listed bricks (`listed`) or over every voxel.
    fn build(ctx: &Arc<Context>, listed: bool) -> Result<ComputePipeline> {
        ComputePipeline::with_constants(
            ctx,
            "render/sobel_normals.comp",
            &NORMALS_BINDINGS,
            std::mem::size_of::<NormalsPush>() as u32,
            &[listed as u32],
        )
    }

    /// The device the pipelines are on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// The pipeline over listed bricks, built on first use.
    fn listed_pipeline(&self) -> Result<&ComputePipeline> {
        if let Some(p) = self.listed.get() {
            return Ok(p);
        }
        let built = Self::build(&self.ctx, true)?;
        Ok(self.listed.get_or_init(|| built))
    }

    /// Uploads `v` normalised (pass `upload`) and computes its gradients (pass `sobel_normals`) in
    /// one submission. Both images end sampled by fragment shaders. Returns the passes' times too.
    pub fn prepare(&self, v: &Volume) -> Result<(VolumeTextures, Vec<PassTime>)> {
        self.prepare_in_range(v, v.normalised_range())
    }

    /// [`Normals::prepare`] with intensities normalised over `range`.
    pub(crate) fn prepare_in_range(
        &self,
        v: &Volume,
        range: [f64; 2],
    ) -> Result<(VolumeTextures, Vec<PassTime>)> {
        let ctx = &self.ctx;
        let source = GradientSource::Stored;
        let (textures, staging) = VolumeTextures::new_in_range(ctx, v, range, source)?;
        let gradient = textures.stored_gradient()?;
        let ((), times) = vellum_gpu::submit_timed(ctx, "volume textures", |f| {
            textures.record_upload(ctx, f, &staging);
            self.record(f, &textures)?;
            textures
                .intensity
                .transition(f.cmd, Access::FragmentSampled);
            gradient.transition(f.cmd, Access::FragmentSampled);
            Ok(())
        })?;
        Ok((textures, times))
    }

    /// Records pass `sobel_normals`: the gradients of `tex.intensity` into `tex.gradient`, which is
    /// left writable-then-readable by later passes (they transition it to their own access).
    /// Nothing for a volume whose gradients are made at each sample.
    pub fn record(&self, frame: &mut Frame, tex: &VolumeTextures) -> Result<()> {
        let Gradients::Stored(gradient) = &tex.gradient else {
            return Ok(());
        };
        let (cmd, profiler) = (frame.cmd, &mut *frame.profiler);
        let (list, active) = &tex.active;
        let push = NormalsPush {
            dims: tex.dims.map(|d| d as i32),
            listed: active.map_or(-1, |n| n as i32),
            inv_spacing: [
                (1.0 / tex.spacing[0]) as f32,
                (1.0 / tex.spacing[1]) as f32,
                (1.0 / tex.spacing[2]) as f32,
                0.0,
            ],
        };
        profiler.begin(cmd, "sobel_normals");
        tex.intensity.transition(cmd, Access::ComputeSampled);
        let (pipeline, groups) = match *active {
            Some(n) => {
                // The bricks of one value: zero gradients. A listed brick is BRICK_GROUPS
                // workgroups (x); the list runs along y, then z past the 65,535 workgroups of
                // one dimension every device takes.
                vellum_gpu::commands::clear_image(&self.ctx, cmd, gradient);
                let rows = (n as u32).clamp(1, MAX_GROUP_ROWS);
                let groups = [BRICK_GROUPS, rows, (n as u32).div_ceil(rows).max(1)];
                (self.listed_pipeline()?, groups)
            }
            None => {
                gradient.discard();
                let extent = tex.intensity.desc.extent;
                let groups = vellum_gpu::pipeline::group_count(extent, GROUP_VOXELS);
                (&self.pipeline, groups)
            }
        };
        gradient.transition(cmd, Access::ComputeWrite);
        pipeline.dispatch(
            cmd,
            &[
                Bind::Sampled(&tex.intensity, &self.nearest),
                Bind::StorageImage(gradient),
                Bind::StorageBuffer(list),
            ],
            &push,
            groups,
        )?;
        profiler.end(cmd);
        Ok(())
    }

    /// The gradients of `v` normalised over `range`, read back: per voxel (x fastest) the
    /// gradient in world units and its length, exactly the half floats the renderer samples.
    pub fn gradients(&self, v: &Volume, range: [f64; 2]) -> Result<Vec<[f32; 4]>> {
        let staged = Self::stage(&self.ctx, v, range)?;
        self.run(&staged)?;
        staged.gradients()
    }

    /// The host's part before a chunk's gradients (no recording, so it may run beside another
    /// thread's passes): `v` normalised over `range` into a staging buffer, its textures and a
    /// readback buffer allocated.
    pub(crate) fn stage(ctx: &Arc<Context>, v: &Volume, range: [f64; 2]) -> Result<StagedNormals> {
        let (textures, upload) =
            VolumeTextures::new_in_range(ctx, v, range, GradientSource::Stored)?;
        let readback = vellum_gpu::transfer::staging_buffer(
            ctx,
            "normals readback",
            textures.stored_gradient()?.byte_size(),
        )?;
        Ok(StagedNormals {
            textures,
            upload,
            readback,
        })
    }

    /// The passes of a staged chunk (`upload`, `sobel_normals`, the readback) in one
    /// submission: the only part that records, for the caller to serialise.
    pub fn run(&self, s: &StagedNormals) -> Result<Vec<PassTime>> {
        let ctx = &self.ctx;
        let gradient = s.textures.stored_gradient()?;
        let ((), times) = vellum_gpu::submit_timed(ctx, "volume gradients", |f| {
            s.textures.record_upload(ctx, f, &s.upload);
            self.record(f, &s.textures)?;
            f.profiler.pass(f.cmd, "readback", |cmd| {
                vellum_gpu::transfer::record_readback(ctx, cmd, gradient, &s.readback)
            });
            Ok(())
        })?;
        Ok(times)
    }

    /// The nearest-texel sampler the pass reads with (also right for `texelFetch` elsewhere).
    pub(crate) fn nearest(&self) -> &Sampler {
        &self.nearest
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    #[test]
    fn brick_ranges_include_the_one_voxel_border() {
        // 20×3×3 ramp along x: brick 0 covers x 0..16 and, widened, reads x 16; brick 1 reads 15..20.
        let dims = [20, 3, 3];
        let texels: Vec<u16> = (0..180).map(|i| (i % 20) as u16 * 100).collect();
        let b = Bricks::new(&texels, dims);
        assert_eq!(b.counts, [2, 1, 1]);
        assert_eq!(b.range, vec![[0, 1600], [1500, 1900]]);
        assert_eq!(b.voxel_bounds(1, dims), ([16, 0, 0], [20, 3, 3]));
    }

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            NormalsPush,
            "render.glsl",
            "NormalsPush",
            [dims, listed, inv_spacing]
        );
        let src = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../glsl/common/render.glsl"
        ))
        .unwrap();
        for (axis, n) in ["X", "Y", "Z"].iter().zip(LOCAL_SIZE) {
            assert!(src.contains(&format!("#define NORMALS_LOCAL_{axis} {n}")));
        }
        assert!(src.contains(&format!("#define NORMALS_COLUMN {COLUMN}")));
        for (axis, n) in ["X", "Y"].iter().zip(BLOCK) {
            assert!(src.contains(&format!("#define NORMALS_BLOCK_{axis} {n}")));
        }
        for g in &GROUP_VOXELS[..2] {
            assert_eq!(BRICK as u32 % g, 0, "a brick is whole workgroups");
        }
        assert_eq!(
            GROUP_VOXELS[2], BRICK as u32,
            "a listed brick's columns span it"
        );
    }
}
