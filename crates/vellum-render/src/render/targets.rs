//! The render targets of a frame as named, persistent layers: `composite`, and for two-level
//! frames `focus.phong`, `focus.diffuse`, `focus.depth` (linear distance along the view direction),
//! its D32 twin used for depth testing, and `context`. They live across frames, are reallocated only
//! when the size changes (the old ones are released once the frames using them complete), and can
//! be sampled by passes recorded after the renderer's (edges, abstraction, lines).

use crate::passes::lines::LineState;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::profiler::PassTime;
use vellum_gpu::transfer::{record_readback, staging_buffer};
use vellum_gpu::Format;
use vellum_gpu::{Buffer, BufferDesc, Context, Frame, Image, ImageDesc};

/// Colour layers: premultiplied RGBA in float.
// RGBA32F: many slices blend into each pixel, which 8 bits would band; EXR keeps the float.
pub(crate) const COLOR: Format = Format::R32G32B32A32_SFLOAT;
/// The linear focus depth.
// R32F: one distance a pixel (+inf where no focus), which the line raster tests against.
pub(crate) const LINEAR_DEPTH: Format = Format::R32_SFLOAT;
/// The depth-test buffer of the focus.
// D32F: float depth, so that the context pass's test against the focus keeps its precision.
pub(crate) const DEPTH: Format = Format::D32_SFLOAT;

/// Names of the layers, as in the EXR output and for [`FrameTargets::layer`].
pub const LAYER_NAMES: [&str; 5] = [
    "focus.phong",
    "focus.diffuse",
    "focus.depth",
    "context",
    "composite",
];

/// The two-level layers.
pub struct TargetLayers {
    /// The focus level with Phong shading, specular included.
    pub focus_phong: Image,
    /// The focus level with diffuse shading only, which the edge passes read.
    pub focus_diffuse: Image,
    /// Linear depth of the nearest focus sample (+inf where none).
    pub focus_depth: Image,
    /// The context level: every other sample, depth-tested against the focus.
    pub context: Image,
    /// D32 depth of the nearest focus sample, tested by the context pass.
    pub depth: Image,
}

/// The images of one size.
pub struct TargetImages {
    /// Width and height in pixels, of every image here.
    pub size: [u32; 2],
    /// The frame as shown: the context over the focus, the one pass's image, or the style's
    /// composite.
    pub composite: Image,
    /// The two-level layers, from the first two-level frame at this size on.
    pub layers: Option<TargetLayers>,
    /// The style passes' images, from the first styled frame on.
    pub post: Option<PostTargets>,
}

/// Persistent targets, resized on demand, and the view's state beside them.
pub struct FrameTargets {
    ctx: Arc<Context>,
    images: Option<TargetImages>,
    two_level: bool,
    state: ViewState,
}

/// What a view keeps between frames besides its images, as kajiya keeps temporal resources: the
/// object-space lines' state (segment buffer, cell list, the seeded traversal's buffers and
/// seed key) and the volume smoothed for them. Each part is made by the first frame that needs
/// it; the renderer borrows it by `&mut` for one frame at a time.
#[derive(Default)]
pub struct ViewState {
    /// From the first frame of a style with lines on.
    pub lines: Option<LineState>,
    smoothed: Option<Smoothed>,
    /// One label segment's field for its lines (`LineExtractor::record_segments`), from the
    /// first frame of a style with lines over a label volume, at that volume's size.
    segment_field: Option<Image>,
    /// The rays' saved states of a bricked frame that waits for its bricks (`passes::paging`),
    /// from the first such frame, for as many pixels as it had.
    rays: Option<(u64, vellum_gpu::Buffer)>,
    /// The sums of the channels that `add` or `max` mixes, per ray of such a frame (eight
    /// RGBA32F a ray), from the first one, for as many rays as it had.
    sums: Option<(u64, vellum_gpu::Buffer)>,
    /// The tiles of 8 × 8 rays of such a frame that a resumed pass runs (`ray_wake.comp`):
    /// its indirect dispatch, then per tile a flag and the list, for as many tiles as it had.
    tiles: Option<(u64, vellum_gpu::Buffer)>,
    /// A bricked volume's page-table words as the last frame staged them.
    page_words: crate::passes::paging::PageWords,
}

/// A bricked frame's buffers per ray ([`ViewState::ray_states`]).
pub(crate) struct RayBuffers<'a> {
    /// The rays' saved states.
    pub(crate) rays: &'a vellum_gpu::Buffer,
    /// The channels' sums, when asked for.
    pub(crate) sums: Option<&'a vellum_gpu::Buffer>,
    /// The tiles' list (`ray_wake.comp`: 4 words of dispatch, a flag per tile, the list), and
    /// how many tiles this frame has.
    pub(crate) tiles: (&'a vellum_gpu::Buffer, u64),
}

/// Bytes of one ray's channel sums (`ChannelSums` in raycast.comp): eight RGBA32F.
const CHANNEL_SUM_BYTES: u64 = 8 * 16;

/// A volume smoothed for line extraction: `VolumeTextures::id` of the source and the radius.
struct Smoothed {
    volume: u64,
    radius: u32,
    image: Image,
}

impl Smoothed {
    /// The image in `slot` when it is volume `volume` smoothed by `radius` (never for radius 0).
    fn kept(slot: &Option<Smoothed>, volume: u64, radius: u32) -> Option<&Image> {
        slot.as_ref()
            .filter(|s| radius > 0 && s.volume == volume && s.radius == radius)
            .map(|s| &s.image)
    }
}

impl ViewState {
    /// The page-table words the last bricked frame of this view staged
    /// (`passes::paging::Paged::page_words`).
    pub(crate) fn page_words(&mut self) -> &mut crate::passes::paging::PageWords {
        &mut self.page_words
    }

    /// The lines' state, made with a buffer of `capacity` segments when this view has none yet,
    /// and the copy of volume `volume` smoothed by `radius` when kept (never for radius 0).
    pub(crate) fn lines_and_smoothed(
        &mut self,
        ctx: &Arc<Context>,
        capacity: u32,
        (volume, radius): (u64, u32),
    ) -> Result<(&mut LineState, Option<&Image>)> {
        if self.lines.is_none() {
            self.lines = Some(LineState::new(ctx, capacity)?);
        }
        let smoothed = Smoothed::kept(&self.smoothed, volume, radius);
        Ok((self.lines.as_mut().expect("made above"), smoothed))
    }

    /// The lines' state and the segment field for a label volume of `dims` voxels (made, or
    /// made again at another size, when needed; the last one is released once the frames
    /// using it complete).
    pub(crate) fn lines_and_segment_field(
        &mut self,
        ctx: &Arc<Context>,
        capacity: u32,
        dims: [usize; 3],
    ) -> Result<(&mut LineState, &Image)> {
        if self.lines.is_none() {
            self.lines = Some(LineState::new(ctx, capacity)?);
        }
        let extent = dims.map(|d| d as u32);
        if self
            .segment_field
            .as_ref()
            .is_none_or(|f| f.desc.extent != extent)
        {
            let desc = ImageDesc::new_3d(Format::R32_SFLOAT, extent);
            self.segment_field = Some(Image::new(ctx, "segment field", &desc)?);
        }
        Ok((
            self.lines.as_mut().expect("made above"),
            self.segment_field.as_ref().expect("made above"),
        ))
    }

    /// The ray states for the rays of an image of `size` pixels, with `sums` the channels' sums
    /// of as many, and the list of its tiles of `tile` pixels (each made, or remade larger, when
    /// needed).
    pub(crate) fn ray_states(
        &mut self,
        ctx: &Arc<Context>,
        (size, tile): ([u32; 2], [u32; 2]),
        sums: bool,
    ) -> Result<RayBuffers<'_>> {
        let pixels = size[0] as u64 * size[1] as u64;
        let tiles = (0..2).map(|a| size[a].div_ceil(tile[a]) as u64).product();
        let wanted = [
            (
                "ray states",
                pixels,
                crate::passes::paging::RAY_STATE_BYTES,
                true,
            ),
            ("channel sums", pixels, CHANNEL_SUM_BYTES, sums),
            // The dispatch and the count (four words), then a flag and a place a tile.
            ("listed tiles", tiles + 2, 8, true),
        ];
        for (slot, (name, n, bytes, wanted)) in [&mut self.rays, &mut self.sums, &mut self.tiles]
            .into_iter()
            .zip(wanted)
        {
            if wanted && slot.as_ref().is_none_or(|(had, _)| *had < n) {
                let mut desc = vellum_gpu::BufferDesc::storage(n.max(1) * bytes);
                if name == "listed tiles" {
                    desc = desc.indirect();
                }
                *slot = Some((n, vellum_gpu::Buffer::new(ctx, name, &desc)?));
            }
        }
        Ok(RayBuffers {
            rays: &self.rays.as_ref().expect("made above").1,
            sums: self.sums.as_ref().filter(|_| sums).map(|s| &s.1),
            tiles: (&self.tiles.as_ref().expect("made above").1, tiles),
        })
    }

    /// Whether the copy of volume `volume` smoothed by `radius` (> 0) is kept.
    pub(crate) fn has_smoothed(&self, volume: u64, radius: u32) -> bool {
        Smoothed::kept(&self.smoothed, volume, radius).is_some()
    }

    /// Keeps `image`, the copy of volume `volume` smoothed by `radius`, in place of the last one
    /// (which is released once the frames using it complete).
    pub(crate) fn keep_smoothed(&mut self, volume: u64, radius: u32, image: Image) {
        self.smoothed = Some(Smoothed {
            volume,
            radius,
            image,
        });
    }
}

fn target(ctx: &Arc<Context>, name: &str, format: Format, [w, h]: [u32; 2]) -> Result<Image> {
    let desc = if format == DEPTH {
        ImageDesc::depth_target(format, [w, h])
    } else {
        ImageDesc::color_target(format, [w, h])
    };
    Image::new(ctx, name, &desc)
}

impl FrameTargets {
    /// No images until the first frame says what size it needs.
    pub fn new(ctx: &Arc<Context>) -> Self {
        FrameTargets {
            ctx: ctx.clone(),
            images: None,
            two_level: false,
            state: ViewState::default(),
        }
    }

    /// Makes sure the targets have `size`, with the two-level layers when `two_level` and the
    /// style passes' images when `styled`. Allocates only on a change of size or the first frame
    /// that needs more. Returns the images and the view's state.
    pub fn ensure(
        &mut self,
        size: [u32; 2],
        two_level: bool,
        styled: bool,
    ) -> Result<(&TargetImages, &mut ViewState)> {
        let ctx = &self.ctx;
        if self.images.as_ref().is_none_or(|i| i.size != size) {
            self.images = Some(TargetImages {
                size,
                composite: target(ctx, "composite", COLOR, size)?,
                layers: None,
                post: None,
            });
        }
        let images = self.images.as_mut().expect("set above");
        if two_level && images.layers.is_none() {
            images.layers = Some(TargetLayers {
                focus_phong: target(ctx, "focus.phong", COLOR, size)?,
                focus_diffuse: target(ctx, "focus.diffuse", COLOR, size)?,
                focus_depth: target(ctx, "focus.depth", LINEAR_DEPTH, size)?,
                context: target(ctx, "context", COLOR, size)?,
                depth: target(ctx, "focus.depth.d32", DEPTH, size)?,
            });
        }
        if styled && images.post.is_none() {
            images.post = Some(PostTargets::new(ctx, size)?);
        }
        self.two_level = two_level;
        Ok((images, &mut self.state))
    }

    /// The view's state: after a styled frame with lines, `lines.buffer` holds its segments.
    pub fn state(&self) -> &ViewState {
        &self.state
    }

    /// The images, once a frame has been recorded.
    pub fn images(&self) -> Option<&TargetImages> {
        self.images.as_ref()
    }

    /// Whether the last frame recorded was a two-level frame (its layers are current).
    pub fn two_level(&self) -> bool {
        self.two_level
    }

    /// A layer of the last frame by name ([`LAYER_NAMES`]); two-level layers only after a
    /// two-level frame.
    pub fn layer(&self, name: &str) -> Option<&Image> {
        let i = self.images.as_ref()?;
        if name == "composite" {
            return Some(&i.composite);
        }
        if name == "style.edges" {
            // The style's edge layer: image-space edges and object-space lines.
            return i.post.as_ref().map(|p| &p.edges);
        }
        let l = i.layers.as_ref().filter(|_| self.two_level)?;
        match name {
            "focus.phong" => Some(&l.focus_phong),
            "focus.diffuse" => Some(&l.focus_diffuse),
            "focus.depth" => Some(&l.focus_depth),
            "context" => Some(&l.context),
            _ => None,
        }
    }
}

/// Host buffers to read the layers of a frame into.
pub struct TargetsReadback {
    size: [u32; 2],
    composite: Buffer,
    /// focus.phong, focus.diffuse, focus.depth, context.
    layers: Option<[Buffer; 4]>,
}

impl TargetsReadback {
    /// Buffers for the current layers of `targets` (composite, plus the two-level layers after a
    /// two-level frame).
    pub fn new(ctx: &Arc<Context>, targets: &FrameTargets) -> Result<Self> {
        let images = targets
            .images()
            .ok_or_else(|| Error::Invalid("no frame has been recorded into the targets".into()))?;
        let buffer =
            |i: &Image| staging_buffer(ctx, &format!("{} readback", i.name), i.byte_size());
        let layers = match (&images.layers, targets.two_level()) {
            (Some(l), true) => Some([
                buffer(&l.focus_phong)?,
                buffer(&l.focus_diffuse)?,
                buffer(&l.focus_depth)?,
                buffer(&l.context)?,
            ]),
            _ => None,
        };
        Ok(TargetsReadback {
            size: images.size,
            composite: buffer(&images.composite)?,
            layers,
        })
    }

    /// Records pass `readback`: the copies of the layers into the buffers.
    pub fn record(&self, frame: &mut Frame, targets: &FrameTargets) {
        let Some(images) = targets.images() else {
            return;
        };
        let (ctx, cmd) = (&targets.ctx, frame.cmd);
        frame.profiler.begin(cmd, "readback");
        record_readback(ctx, cmd, &images.composite, &self.composite);
        if let (Some(b), Some(l)) = (&self.layers, &images.layers) {
            for (image, buffer) in [&l.focus_phong, &l.focus_diffuse, &l.focus_depth, &l.context]
                .into_iter()
                .zip(b)
            {
                record_readback(ctx, cmd, image, buffer);
            }
        }
        frame.profiler.end(cmd);
    }

    /// The composite and the layers, once the frame that recorded the copies has completed.
    pub fn read(&self) -> Result<(Vec<[f32; 4]>, Option<Layers>)> {
        let bytes = |b: &Buffer| -> Result<Vec<u8>> {
            b.mapped()
                .map(<[u8]>::to_vec)
                .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))
        };
        let rgba =
            |b: &Buffer| -> Result<Vec<[f32; 4]>> { Ok(bytemuck::pod_collect_to_vec(&bytes(b)?)) };
        let layers = match &self.layers {
            Some([phong, diffuse, depth, context]) => Some(Layers {
                focus_phong: rgba(phong)?,
                focus_diffuse: rgba(diffuse)?,
                focus_depth: bytemuck::pod_collect_to_vec(&bytes(depth)?),
                context: rgba(context)?,
            }),
            None => None,
        };
        Ok((rgba(&self.composite)?, layers))
    }

    /// The size of the frame the buffers hold.
    pub fn size(&self) -> [u32; 2] {
        self.size
    }
}

/// Passes of Canny's hysteresis (see `render::post`'s doc), whose change counters
/// [`PostTargets`] holds.
pub(crate) const HYSTERESIS_PASSES: u32 = 16;

/// The images the post passes work in, for one size.
pub struct PostTargets {
    /// Width and height in pixels.
    pub size: [u32; 2],
    /// Luminance of focus.diffuse.
    pub luminance: Image,
    /// Blur scratch and results.
    pub(crate) tmp: Image,
    /// The first Gaussian blur of the luminance: DoG's narrow one, Canny's smoothing.
    pub(crate) blur_a: Image,
    /// The second blur, DoG's wide one (σ · k).
    pub(crate) blur_b: Image,
    /// Sobel gradient (gx, gy, normalised magnitude).
    pub gradient: Image,
    /// Edge strength in [0, 1], or Canny's classes (2 edge, 1 weak, 0 none).
    pub edges: Image,
    /// The abstracted context.
    pub context: Image,
    /// Hysteresis change counters, one per pass plus one.
    pub changed: Buffer,
}

impl PostTargets {
    /// Allocates the images for `size`.
    pub fn new(ctx: &Arc<Context>, size: [u32; 2]) -> Result<Self> {
        let desc = |format| ImageDesc::storage_2d(format, size);
        let image = |name: &str, format| Image::new(ctx, name, &desc(format));
        // R32F for the one-channel images (luminance, blurs, edges), RGBA32F for the gradient and
        // the abstracted context: float, as the layers they are computed from.
        let r32 = Format::R32_SFLOAT;
        let rgba = Format::R32G32B32A32_SFLOAT;
        Ok(PostTargets {
            size,
            luminance: image("post.luminance", r32)?,
            tmp: image("post.tmp", r32)?,
            blur_a: image("post.blur_a", r32)?,
            blur_b: image("post.blur_b", r32)?,
            gradient: image("post.gradient", rgba)?,
            // Lines are drawn into the edges with atomic max on the R32_UINT view: coverage is a
            // non-negative float, whose bits order as unsigned integers do.
            edges: Image::new(ctx, "post.edges", &desc(r32).alias(Format::R32_UINT))?,
            context: image("post.context", rgba)?,
            changed: Buffer::new(
                ctx,
                "post.changed",
                &BufferDesc::storage(4 * (HYSTERESIS_PASSES as u64 + 1)),
            )?,
        })
    }

    /// Whether the last recorded hysteresis converged: reads the last change counter back (tests
    /// and diagnostics; a frame never waits for it).
    pub fn hysteresis_converged(&self, ctx: &Arc<Context>) -> Result<bool> {
        let bytes = vellum_gpu::transfer::readback_buffer(ctx, &self.changed)?;
        let counters: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
        Ok(counters.last() == Some(&0))
    }
}

/// The layers of a two-level frame, premultiplied RGBA rows top to bottom.
#[derive(Clone, Debug)]
pub struct Layers {
    /// The focus level with Phong shading.
    pub focus_phong: Vec<[f32; 4]>,
    /// The focus level with diffuse shading only.
    pub focus_diffuse: Vec<[f32; 4]>,
    /// Distance along the view direction of the nearest focus sample; +inf where there is none.
    pub focus_depth: Vec<f32>,
    /// The context level.
    pub context: Vec<[f32; 4]>,
}

/// A rendered frame on the host: what a readback brings back.
#[derive(Clone, Debug)]
pub struct FrameImage {
    /// Width and height in pixels.
    pub size: [u32; 2],
    /// Premultiplied RGBA over transparent black (empty when not read back).
    pub composite: Vec<[f32; 4]>,
    /// The two-level layers (two-level frames read back only).
    pub layers: Option<Layers>,
    /// GPU ms of `focus`, `context`, `composite` or `one_pass`, and `readback` when read back.
    pub passes: Vec<PassTime>,
    /// Planes drawn (or sampled by the rays).
    pub slices: u32,
    /// The geometry the frame's object-space lines were drawn with (styles with lines).
    pub lines: Option<crate::passes::lines::RasterView>,
    /// Those lines' segments and how many were found (more than kept when the buffer
    /// overflowed), when the frame was read back.
    pub segments: Option<(Vec<vellum_volume::lines::Segment>, u64)>,
}

impl FrameImage {
    /// Writes the frame's layers as named float channels to one OpenEXR file: focus.phong,
    /// focus.diffuse (RGBA), focus.depth (Z) and context for two-level frames, and composite.
    pub fn write_exr(&self, path: &std::path::Path) -> Result<()> {
        use vellum_volume::output::{write_exr_layers, ExrChannels, ExrLayer};
        let mut layers = Vec::new();
        if let Some(l) = &self.layers {
            layers.push(ExrLayer {
                name: "focus.phong",
                channels: ExrChannels::Rgba(&l.focus_phong),
            });
            layers.push(ExrLayer {
                name: "focus.diffuse",
                channels: ExrChannels::Rgba(&l.focus_diffuse),
            });
            layers.push(ExrLayer {
                name: "focus.depth",
                channels: ExrChannels::Depth(&l.focus_depth),
            });
            layers.push(ExrLayer {
                name: "context",
                channels: ExrChannels::Rgba(&l.context),
            });
        }
        layers.push(ExrLayer {
            name: "composite",
            channels: ExrChannels::Rgba(&self.composite),
        });
        write_exr_layers(path, self.size[0], self.size[1], &layers)
    }
}

/// Premultiplied RGBA over an opaque `background`, as 8-bit RGB for PNG.
pub fn to_rgb8(pixels: &[[f32; 4]], background: [f32; 3]) -> Vec<u8> {
    pixels
        .iter()
        .flat_map(|p| {
            let a = p[3].clamp(0.0, 1.0);
            [0, 1, 2]
                .map(|c| ((p[c] + (1.0 - a) * background[c]).clamp(0.0, 1.0) * 255.0).round() as u8)
        })
        .collect()
}
