//! Loading a volume for the viewer on a worker thread: the input opened by the session's rule
//! within the GPU budget, its statistics, and the transfer function the panels start from.

use std::sync::Arc;
use vellum_error::Result;
use vellum_render::classify::otf::OcclusionTf;
use vellum_render::classify::transfer::TransferFunction;
use vellum_render::classify::Classification;
use vellum_render::render::scene::Scene;
use vellum_render::render::session::{Opened, SessionOptions};
use vellum_volume::Volume;

/// What a volume opens within: bytes of GPU memory for its textures (a store that needs more is
/// streamed), and the session's options (host memory for a streamed one: `--memory-budget`).
#[derive(Clone, Debug)]
pub(crate) struct Budget {
    pub(crate) gpu: u64,
    pub(crate) session: SessionOptions,
}

impl Budget {
    /// `gpu` bytes, and the session's defaults.
    #[cfg(test)]
    pub(crate) fn gpu(gpu: u64) -> Self {
        Budget {
            gpu,
            session: SessionOptions::default(),
        }
    }
}

/// A volume loaded on a worker thread.
pub(crate) struct Loaded {
    pub(crate) scene: Scene,
    /// The volume, or for a store streamed through the brick cache its coarsest level (which the
    /// histogram and range come from), with the pyramid in `levels`.
    pub(crate) volume: Volume,
    pub(crate) levels: Option<Arc<vellum_volume::bricks::BrickLevels>>,
    pub(crate) classification: Classification,
    pub(crate) tf: TransferFunction,
    pub(crate) histogram: Vec<u64>,
    pub(crate) range: [f64; 2],
    pub(crate) features: Option<vellum_volume::feature::FeatureMap>,
    pub(crate) otf: Option<OcclusionTf>,
    /// The input's time points (a store's t axis; 1 otherwise).
    pub(crate) times: usize,
}

/// Opens `scene`'s input by the session's rule within `budget`'s bytes of GPU memory: a store
/// beyond the budget is never read whole, and its level of at most 64³ voxels stands in for it
/// on the host (histogram, range); a volume beyond it is drawn through the brick cache too.
pub(crate) fn load(scene: Scene, budget: &Budget) -> Result<Loaded> {
    load_with(scene, budget, None)
}

/// [`load`] of another time point of the series shown, whose transfer function (`look`, as
/// edited) and histogram the session keeps (`SeriesLook`): on the series' scale
/// (`input.range`), it is neither windowed nor counted again.
pub(crate) fn load_time_point(
    scene: Scene,
    budget: &Budget,
    look: TransferFunction,
) -> Result<Loaded> {
    load_with(scene, budget, Some(look))
}

fn load_with(scene: Scene, budget: &Budget, look: Option<TransferFunction>) -> Result<Loaded> {
    let classification = scene.classification()?;
    let cache = budget.session.chunk_cache_bytes;
    let (levels, volume) = match Opened::open(&scene, None, budget.gpu, cache)? {
        Opened::Bricked(levels) => {
            let mib = budget.gpu as f64 / (1 << 20) as f64;
            log::info!(
                "{}: larger than the GPU budget ({mib:.0} MiB); streamed through the brick cache",
                scene.input.path
            );
            let small = levels.read_small_level(64 * 64 * 64)?;
            (Some(levels), small)
        }
        Opened::InCore(v) => (None, v),
    };
    let kept = matches!(
        classification,
        Classification::Auto | Classification::Transfer(_)
    );
    let (tf, histogram, range, features) = match (look, scene.input.range) {
        (Some(tf), Some(range)) if kept => (tf, Vec::new(), range, None),
        _ => described(&scene, &classification, &volume, levels.as_deref())?,
    };
    let otf = match &classification {
        Classification::Occlusion(o) => Some(o.clone()),
        _ => None,
    };
    Ok(Loaded {
        otf,
        times: crate::timeline::times_of(&scene),
        scene,
        classification,
        tf,
        histogram,
        range,
        volume,
        levels,
        features,
    })
}

/// The transfer function the panels start from, the histogram, the range and the feature map
/// of a volume just read (for a store streamed, its small level `volume`).
#[allow(clippy::type_complexity)]
fn described(
    scene: &Scene,
    classification: &Classification,
    volume: &Volume,
    levels: Option<&vellum_volume::bricks::BrickLevels>,
) -> Result<(
    TransferFunction,
    Vec<u64>,
    [f64; 2],
    Option<vellum_volume::feature::FeatureMap>,
)> {
    let s = vellum_volume::stats::stats(volume, 256);
    // A time point of a series after the first shown is drawn on that one's scale.
    let range = match (scene.input.range, levels) {
        (Some(r), _) => r,
        (None, Some(l)) => l.range(),
        (None, None) => [s.min, s.max],
    };
    let tf = match classification {
        Classification::Transfer(tf) => tf.clone(),
        Classification::Auto => vellum_render::classify::window::auto(volume, range)?,
        _ => TransferFunction::preset("grey")?,
    };
    let (tf, features) = match classification {
        Classification::Features(map) => (
            vellum_render::classify::features::feature_transfer_function(map, [s.min, s.max])?,
            Some(map.clone()),
        ),
        _ => (tf, None),
    };
    Ok((tf, s.histogram, range, features))
}
