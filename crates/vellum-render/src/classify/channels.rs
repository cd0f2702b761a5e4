//! Several channels of a store mixed in one ray (issue 42): each channel has its own transfer
//! function over its own range, and the ray caster mixes the channels' classified samples at
//! every sample (`raycast.comp`, `channels` and `channel_tf`).
//!
//! - `over` composites the channels' premultiplied colours at each sample, the first listed on
//!   top; the mixed colour and opacity then go on as one sample's (shading, the opacity
//!   correction, the two levels).
//! - `add` composites each channel along the ray on its own (emission and absorption, no
//!   channel hiding another) and adds the results, unlit: the fluorescence look. Swapping the
//!   channels changes nothing.
//! - `max` projects each channel to its maximum along the ray, then adds their colours.
//!
//! `add` and `max` are projections of one level: no focus level, styles or labels.
//!
//! The channel the two levels, the gradient (shading), importance modulation and the lines work
//! on is the focus channel, the first listed unless `focus_channel` says otherwise; it is also
//! the volume every other pass sees. Up to [`MAX_CHANNELS`] channels, up to four to a texture.

use crate::classify::transfer::{ControlPoint, TransferFunction};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::commands::{copy_slice_to_buffer, memory_transition};
use vellum_gpu::{Access, Buffer, BufferDesc, Context, Format, Frame, Image, ImageDesc};
use vellum_volume::io::ome_zarr::{Multiscale, OmeroChannel, Pick};
use vellum_volume::Volume;

/// Edge of the bricks whose ranges decide skipping: the volume's (`passes::normals::BRICK`).
const BRICK: usize = 16;

/// The most channels mixed in one ray (two RGBA textures).
pub const MAX_CHANNELS: usize = 8;

/// Voxels of the level a channel's default window is measured on at most (its finest of at most
/// this many): 2 Mi.
pub const DESCRIBE_VOXELS: usize = 1 << 21;

/// Channels per RGBA texture.
const PER_TEXTURE: usize = 4;

/// How the channels' samples are mixed.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mix {
    /// Premultiplied colours composited at each sample, the first channel on top.
    #[default]
    Over,
    /// Premultiplied colours added (emission).
    Add,
    /// Each channel's maximum along the ray, their colours added.
    Max,
}

impl Mix {
    /// `over`, `add` or `max`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "over" => Ok(Mix::Over),
            "add" => Ok(Mix::Add),
            "max" => Ok(Mix::Max),
            _ => Err(Error::Invalid(format!(
                "`mix` {s:?} is unknown; expected over, add or max"
            ))),
        }
    }
}

/// The channels of a store a scene mixes, as the flags and a scene file give them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSpec {
    /// The channels, in mixing order (`over` puts the first on top).
    pub channels: Vec<usize>,
    /// How they are mixed.
    #[serde(default)]
    pub mix: Mix,
    /// Transfer functions by channel: a preset or a JSON file, over the channel's own range.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tfs: Vec<(usize, String)>,
    /// Scales fixed for the frames of a series (time point 0's, [`ChannelSpec::series_scales`]);
    /// a channel without one is drawn on its own values, or at a later time point on time point
    /// 0's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub scales: Vec<ChannelScale>,
}

/// A channel's scale, fixed for every frame of a series: the values its texture spans, and the
/// transfer function it is drawn with where none is given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelScale {
    /// The channel's index in the store.
    pub channel: usize,
    /// The values its texture maps to 0 and 1.
    pub range: [f64; 2],
    /// Its transfer function over that range.
    pub tf: TransferFunction,
}

/// Colours of channels without NGFF `omero` colours: green, magenta, cyan, yellow, then red,
/// blue, orange and white (the first four are the common fluorescence look).
const PALETTE: [[f32; 3]; MAX_CHANNELS] = [
    [0.0, 1.0, 0.0],
    [1.0, 0.0, 1.0],
    [0.0, 1.0, 1.0],
    [1.0, 1.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.5, 0.0],
    [1.0, 1.0, 1.0],
];

/// One channel on the host: its voxels, the range its texture spans, and its transfer function.
pub struct Channel {
    /// Its name in the store's NGFF `omero` metadata, if any.
    pub name: Option<String>,
    /// Its index in the store.
    pub index: usize,
    /// Its voxels at the level drawn.
    pub volume: Volume,
    /// The values its texture maps to 0 and 1.
    pub range: [f64; 2],
    /// Its transfer function over that range.
    pub tf: TransferFunction,
}

impl ChannelSpec {
    /// Reads the channels from the store `path` at `time`, each with its transfer function: the
    /// one given, else a ramp in the channel's NGFF `omero` colour over its `omero` window, else
    /// in a palette colour over its `auto` window.
    ///
    /// A default window is measured on the channel's finest level of at most
    /// [`DESCRIBE_VOXELS`], in core and through the brick cache alike, so that a channel looks
    /// the same whichever way it is drawn.
    pub fn read(&self, path: &Path, time: Option<usize>) -> Result<Vec<Channel>> {
        self.read_at(path, time, false)
    }

    /// [`ChannelSpec::read`], or with `paged` for a store drawn through the brick cache: each
    /// channel's `volume` is then the level its window is measured on (never level 0 whole,
    /// unless it is that small), and its range the one the store records for it, else that
    /// level's.
    pub fn read_at(&self, path: &Path, time: Option<usize>, paged: bool) -> Result<Vec<Channel>> {
        if self.channels.len() > MAX_CHANNELS {
            return Err(Error::Invalid(format!(
                "`channels` names {} channels; vellum mixes at most {MAX_CHANNELS} in one ray",
                self.channels.len()
            )));
        }
        if let Some((c, _)) = self.tfs.iter().find(|(c, _)| !self.channels.contains(c)) {
            return Err(Error::Invalid(format!(
                "a transfer function is given for channel {c}, which `channels` does not list"
            )));
        }
        // A later time point without scales is drawn on time point 0's, as `series_scale` draws
        // the volume: frame T of a series is what `--time T` alone draws.
        let first;
        let scales = match time.unwrap_or(0) > 0 && self.scales.is_empty() {
            true => {
                first = self.series_scales(path, paged)?;
                &first
            }
            false => &self.scales,
        };
        let mut out = Vec::with_capacity(self.channels.len());
        for (k, &c) in self.channels.iter().enumerate() {
            let pick = Pick {
                time,
                channel: Some(c),
            };
            let ms = Multiscale::open_picked(path, pick)?;
            let small = ms
                .finest_within(DESCRIBE_VOXELS)
                .unwrap_or(ms.levels.len() - 1);
            let described = ms.read_level(small)?;
            let volume = match (paged, small) {
                (false, 1..) => ms.read_level(0)?,
                _ => described.clone(),
            };
            let own = match (paged, ms.range) {
                (true, Some(r)) => r,
                _ => volume.normalised_range(),
            };
            let scale = scales.iter().find(|s| s.channel == c);
            let range = scale.map_or(own, |s| s.range);
            let omero = ms.omero.get(c);
            let given = self
                .tfs
                .iter()
                .find(|(i, _)| *i == c)
                .map(|(_, t)| t.as_str());
            let tf = match (given, scale) {
                (Some(t), _) => named_or_file(t)?,
                (None, Some(s)) => s.tf.clone(),
                (None, None) => default_tf(&described, range, omero, PALETTE[k % MAX_CHANNELS])?,
            };
            out.push(Channel {
                name: omero.and_then(|o| o.label.clone()),
                index: c,
                volume,
                range,
                tf,
            });
        }
        Ok(out)
    }

    /// Time point 0's scale of every channel: the range and transfer function each later frame
    /// of a series is drawn with (read once by a front end that draws many).
    /// With `paged`, as [`ChannelSpec::read_at`] reads them for the brick cache (never level 0
    /// whole).
    pub fn series_scales(&self, path: &Path, paged: bool) -> Result<Vec<ChannelScale>> {
        let first = ChannelSpec {
            scales: Vec::new(),
            ..self.clone()
        };
        let channels = first.read_at(path, Some(0), paged)?;
        Ok(channels
            .into_iter()
            .map(|c| ChannelScale {
                channel: c.index,
                range: c.range,
                tf: c.tf,
            })
            .collect())
    }
}

/// A preset or a JSON file.
fn named_or_file(t: &str) -> Result<TransferFunction> {
    match crate::classify::transfer::PRESETS.contains(&t) {
        true => TransferFunction::preset(t),
        false => TransferFunction::load(Path::new(t)),
    }
}

/// A ramp in one colour: transparent below the window, opacity rising across it.
fn default_tf(
    v: &Volume,
    range: [f64; 2],
    omero: Option<&OmeroChannel>,
    palette: [f32; 3],
) -> Result<TransferFunction> {
    let width = (range[1] - range[0]).max(f64::MIN_POSITIVE);
    let norm = |x: f64| ((x - range[0]) / width).clamp(0.0, 1.0) as f32;
    let (colour, [lo, hi]) = match omero {
        Some(o) => (
            o.colour.map(|c| c as f32 / 255.0),
            o.window.map_or_else(
                || crate::classify::window::auto_window(v, range),
                |w| [norm(w[0]), norm(w[1])],
            ),
        ),
        None => (palette, crate::classify::window::auto_window(v, range)),
    };
    ramp(colour, [lo, hi])
}

/// A ramp in `colour`: transparent up to `lo`, opacity rising to 1 at `hi` (both on the
/// channel's normalised range). The two lowest texels (knots 0 and 1/255) stay transparent, so
/// that the empty background of a channel adds nothing along a ray and its bricks are skipped.
pub fn ramp(colour: [f32; 3], [lo, hi]: [f32; 2]) -> Result<TransferFunction> {
    let lo = lo.max(1.0 / (crate::classify::transfer::TF_SIZE - 1) as f32);
    let hi = hi.max(lo + 1e-3).min(1.0);
    let mut points = vec![ControlPoint {
        x: 0.0,
        rgba: [colour[0], colour[1], colour[2], 0.0],
    }];
    if lo > 0.0 {
        points.push(ControlPoint {
            x: lo,
            rgba: [colour[0], colour[1], colour[2], 0.0],
        });
    }
    points.push(ControlPoint {
        x: hi,
        rgba: [colour[0], colour[1], colour[2], 1.0],
    });
    if hi < 1.0 {
        points.push(ControlPoint {
            x: 1.0,
            rgba: [colour[0], colour[1], colour[2], 1.0],
        });
    }
    TransferFunction::new("channel", points)
}

/// A channel's transfer-function table and its bricks' ranges.
pub type ChannelSkip = (Vec<[f32; 4]>, Vec<[u16; 2]>);

/// Channels on the GPU: 16-bit textures of one, two or four components (channel k in component
/// k % 4 of texture k / 4, each over its own range) and their transfer functions (row k of a
/// 256 × n table).
pub struct GpuChannels {
    /// The voxels of channels 0–3.
    pub image: Image,
    /// The voxels of channels 4–7, with more than four.
    pub image_hi: Option<Image>,
    /// Their transfer functions.
    pub tfs: Image,
    /// Per channel, the opacity bounds of its function's 256 texels (f32 bits), which the ray
    /// caster's walk tests a sample against before classifying it.
    pub bounds: vellum_gpu::Buffer,
    /// How the ray caster mixes them.
    pub mix: Mix,
    /// How many.
    pub count: usize,
    /// The component of the focus channel, whose values equal the volume's intensity texture's
    /// (its range is the volume's): the ray caster reads a sample's intensity from it.
    pub focus: usize,
    /// Per channel, its transfer function's table and its bricks' ranges (16³ bricks widened by
    /// a voxel, as the volume's): a brick none of whose channels can be visible is skipped.
    pub skipping: Vec<ChannelSkip>,
    /// Per channel, what a viewer's channel list shows: name, range, histogram and function.
    pub info: Vec<ChannelInfo>,
    /// Functions set since the last frame, uploaded by the next one ([`GpuChannels::record`]).
    pending: bool,
    ctx: Arc<Context>,
}

/// One mixed channel as a viewer lists it.
#[derive(Clone, Debug)]
pub struct ChannelInfo {
    /// Its index in the store.
    pub index: usize,
    /// Its NGFF `omero` name, if any.
    pub name: Option<String>,
    /// The values its texture spans (its transfer function's 0 and 1).
    pub range: [f64; 2],
    /// 256 bins of its voxels over that range.
    pub histogram: Vec<u64>,
    /// Its transfer function as drawn.
    pub tf: TransferFunction,
}

impl GpuChannels {
    /// `channels` on the GPU, mixed by `mix`; all on one grid. Channel `focus` (an index into
    /// `channels`) is the volume's, whose `range` its texture takes.
    pub fn new(
        ctx: &Arc<Context>,
        channels: &[Channel],
        mix: Mix,
        (focus, range): (usize, [f64; 2]),
    ) -> Result<Self> {
        check_count(channels.len())?;
        let n = channels.len();
        let dims = channels.first().map_or([1; 3], |c| c.volume.dims);
        if let Some(c) = channels.iter().find(|c| c.volume.dims != dims) {
            return Err(Error::Invalid(format!(
                "channel {} is not on the grid of channel {}; expected channels of one grid",
                c.index, channels[0].index
            )));
        }
        let voxels = dims.iter().product::<usize>();
        let size = crate::classify::transfer::TF_SIZE;
        // Per texture, its channels' components (one, two, or four with a third's padded).
        let widths: Vec<usize> = (0..n.div_ceil(PER_TEXTURE))
            .map(|t| match (n - t * PER_TEXTURE).min(PER_TEXTURE) {
                3 => 4,
                w => w,
            })
            .collect();
        let mut texels: Vec<Vec<u16>> = widths.iter().map(|w| vec![0u16; w * voxels]).collect();
        let mut skipping = Vec::with_capacity(n);
        let info = channels.iter().map(ChannelInfo::of).collect();
        for (k, c) in channels.iter().enumerate() {
            // As the intensity texture is made, so that the focus channel's equal it.
            let (own, _) = c
                .volume
                .normalised_u16_in(if k == focus { range } else { c.range });
            let (texture, component) = (k / PER_TEXTURE, k % PER_TEXTURE);
            let w = widths[texture];
            for (i, &t) in own.iter().enumerate() {
                texels[texture][w * i + component] = t;
            }
            let (_, ranges) = vellum_volume::bricks::widened_ranges(&own, dims, BRICK);
            skipping.push((c.tf.table(size), ranges));
        }
        let extent = dims.map(|d| d as u32);
        // 16-bit unorm components: each channel at 16 bits over its range, filtered linearly as
        // the intensity is. Two channels take RG16, half the bytes of RGBA16 to fetch and filter
        // (a CPU device filters every component in software).
        let mut images = texels
            .iter()
            .zip(&widths)
            .enumerate()
            .map(|(i, (texels, w))| {
                let name = ["channels 0-3", "channels 4-7"][i];
                let format = match w {
                    1 => Format::R16_UNORM,
                    2 => Format::R16G16_UNORM,
                    _ => Format::R16G16B16A16_UNORM,
                };
                let image = Image::new(ctx, name, &ImageDesc::new_3d(format, extent))?;
                vellum_gpu::transfer::upload(
                    ctx,
                    &image,
                    bytemuck::cast_slice(texels),
                    Access::ComputeSampled,
                )?;
                Ok::<_, Error>(image)
            });
        let image = images
            .next()
            .ok_or_else(|| Error::Invalid("no channels".into()))??;
        let image_hi = images.next().transpose()?;
        Self::with_images(ctx, (image, image_hi), (skipping, info), (mix, focus))
    }

    /// The channels of a volume drawn through the brick cache, whose pools
    /// (`passes::paging::ChannelPools`) hold their voxels: here only their transfer functions
    /// and what a viewer lists, from each channel's `volume` (a small level). The one brick of
    /// the cache's in-core table is visible to every channel: the page table decides.
    pub fn new_paged(
        ctx: &Arc<Context>,
        channels: &[Channel],
        mix: Mix,
        focus: usize,
    ) -> Result<Self> {
        check_count(channels.len())?;
        let size = crate::classify::transfer::TF_SIZE;
        let skipping = channels
            .iter()
            .map(|c| (c.tf.table(size), vec![[0, u16::MAX]]))
            .collect();
        let info = channels.iter().map(ChannelInfo::of).collect();
        // Sampled nowhere (the pools are bound in their place): one texel.
        let stand_in = Image::new(
            ctx,
            "channels (in the brick cache)",
            &ImageDesc::new_3d(Format::R16_UNORM, [1, 1, 1]),
        )?;
        vellum_gpu::transfer::upload(ctx, &stand_in, &[0, 0], Access::ComputeSampled)?;
        Self::with_images(ctx, (stand_in, None), (skipping, info), (mix, focus))
    }

    /// The channels with their voxels' `images` (channels 0-3, 4-7), their functions' tables
    /// and bricks' ranges (`skipping`), what a viewer lists (`info`), mixed by `mix` with the
    /// focus channel's component `focus`.
    fn with_images(
        ctx: &Arc<Context>,
        (image, image_hi): (Image, Option<Image>),
        (skipping, info): (Vec<ChannelSkip>, Vec<ChannelInfo>),
        (mix, focus): (Mix, usize),
    ) -> Result<Self> {
        let n = skipping.len();
        let size = crate::classify::transfer::TF_SIZE;
        let table: Vec<[f32; 4]> = skipping
            .iter()
            .flat_map(|(t, _)| t.iter().copied())
            .collect();
        // RGBA32F, as the 1D transfer function's texture.
        let tfs = Image::new(
            ctx,
            "channel transfer functions",
            &ImageDesc::new_2d(Format::R32G32B32A32_SFLOAT, [size as u32, n as u32]),
        )?;
        vellum_gpu::transfer::upload(
            ctx,
            &tfs,
            bytemuck::cast_slice(&table),
            Access::ComputeSampled,
        )?;
        // Device-local, written by the frames that record bounds, the first one included.
        let words = 4 * bounds_of(&skipping).len() as u64;
        let bounds = Buffer::new(ctx, "channel opacity bounds", &BufferDesc::storage(words))?;
        Ok(GpuChannels {
            image,
            image_hi,
            tfs,
            bounds,
            mix,
            count: n,
            focus,
            skipping,
            info,
            pending: true,
            ctx: ctx.clone(),
        })
    }

    /// Draws the channels with `tfs` (one per channel, in mixing order) from the next frame on:
    /// a viewer's edit of a channel's visibility, colour or window.
    pub fn set_tfs(&mut self, tfs: &[TransferFunction]) -> Result<()> {
        if tfs.len() != self.count {
            return Err(Error::Invalid(format!(
                "{} transfer functions for {} channels; expected one per channel",
                tfs.len(),
                self.count
            )));
        }
        let size = crate::classify::transfer::TF_SIZE;
        for (k, tf) in tfs.iter().enumerate() {
            if self.info[k].tf != *tf {
                self.skipping[k].0 = tf.table(size);
                self.info[k].tf = tf.clone();
                self.pending = true;
            }
        }
        Ok(())
    }

    /// Records the upload of functions set since the last frame (their table and opacity
    /// bounds), ordered after the previous frames' reads and before this one's.
    pub(crate) fn record(&mut self, frame: &mut Frame) -> Result<()> {
        if !std::mem::take(&mut self.pending) {
            return Ok(());
        }
        let ctx = self.ctx.clone();
        let table: Vec<[f32; 4]> = self
            .skipping
            .iter()
            .flat_map(|(t, _)| t.iter().copied())
            .collect();
        let src = frame.staging.push(bytemuck::cast_slice(&table), 16)?;
        vellum_gpu::transfer::record_upload_from(
            &ctx,
            frame.cmd,
            src,
            &self.tfs,
            Access::ComputeSampled,
        );
        let src = frame
            .staging
            .push(bytemuck::cast_slice(&bounds_of(&self.skipping)), 16)?;
        memory_transition(&ctx, frame.cmd, Access::ComputeRead, Access::TransferWrite);
        copy_slice_to_buffer(&ctx, frame.cmd, &src, &self.bounds);
        memory_transition(&ctx, frame.cmd, Access::TransferWrite, Access::ComputeRead);
        Ok(())
    }
}

impl ChannelInfo {
    /// What a viewer lists of `c`: its histogram over its voxels (the level read).
    fn of(c: &Channel) -> Self {
        ChannelInfo {
            index: c.index,
            name: c.name.clone(),
            range: c.range,
            histogram: vellum_volume::stats::stats(&c.volume, 256).histogram,
            tf: c.tf.clone(),
        }
    }
}

/// 1 to [`MAX_CHANNELS`] channels, or one sentence.
fn check_count(n: usize) -> Result<()> {
    match (1..=MAX_CHANNELS).contains(&n) {
        true => Ok(()),
        false => Err(Error::Invalid(format!(
            "{n} channels to mix; vellum mixes 1 to {MAX_CHANNELS} in one ray"
        ))),
    }
}

/// Per channel, the opacity bounds of its function's texels (f32 bits), as the walk reads them.
fn bounds_of(skipping: &[ChannelSkip]) -> Vec<u32> {
    skipping
        .iter()
        .flat_map(|(t, _)| crate::classify::transfer::opacity_bounds(t).map(f32::to_bits))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mixes_parse_and_refuse_in_one_sentence() {
        assert_eq!(Mix::parse("add").unwrap(), Mix::Add);
        let e = Mix::parse("screen").unwrap_err().to_string();
        assert!(e.contains("expected over, add or max"), "{e}");
    }

    #[test]
    fn the_default_ramp_is_in_the_omero_colour_over_its_window() {
        let v = Volume::new(
            [4, 1, 1],
            [1.0; 3],
            vellum_volume::VoxelData::U16(vec![0, 100, 200, 300]),
        )
        .unwrap();
        let mut omero = OmeroChannel {
            colour: [255, 0, 0],
            window: Some([75.0, 150.0]),
            active: true,
            label: None,
        };
        let tf = default_tf(&v, [0.0, 300.0], Some(&omero), PALETTE[0]).unwrap();
        assert_eq!(tf.sample(0.2)[3], 0.0);
        assert_eq!(tf.sample(0.5)[3], 1.0);
        assert_eq!(&tf.sample(0.5)[..3], &[1.0, 0.0, 0.0]);
        let mid = tf.sample(0.375)[3];
        assert!((mid - 0.5).abs() < 0.01, "{mid}");
        // A window from 0 leaves the lowest texel transparent.
        omero.window = Some([0.0, 150.0]);
        let tf = default_tf(&v, [0.0, 300.0], Some(&omero), PALETTE[0]).unwrap();
        assert_eq!(tf.table(256)[0][3], 0.0);
    }
}
