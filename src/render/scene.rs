//! Everything a frame needs that is computed once per volume: the volume textures and normals,
//! and the classification. The classification is one of: a 1D transfer function; a feature map
//! turned into one (FM6); or an occlusion transfer function with its occlusion volume (OS4).

use crate::error::Result;
use crate::gpu::{Context, PassTime, Profiler};
use crate::passes::normals::{Normals, VolumeTextures};
use crate::passes::occlusion::{parse_mapping, Occlusion, OcclusionParams};
use crate::render::features::feature_transfer_function;
use crate::render::otf::OcclusionTf;
use crate::render::transfer::TransferFunction;
use crate::volume::feature::FeatureMap;
use crate::volume::Volume;
use std::sync::Arc;

/// How samples get colour and opacity.
pub enum Classification {
    /// A 1D transfer function.
    Transfer(TransferFunction),
    /// A feature map: each feature's private interval in its colour (FM6).
    Features(FeatureMap),
    /// An occlusion transfer function; its occlusion volume is computed here.
    Occlusion(OcclusionTf),
}

/// A prepared volume.
pub struct Scene {
    pub textures: VolumeTextures,
    /// The 1D transfer function (unused by the shaders when `occlusion_tf` is set).
    pub transfer: TransferFunction,
    /// The 256×256 occlusion transfer-function table, when classifying by occlusion.
    pub occlusion_tf: Option<Vec<[f32; 4]>>,
    /// GPU time of `upload`, `sobel_normals` and, for occlusion, `occlusion`.
    pub passes: Vec<PassTime>,
}

/// Uploads `v`, computes its normals (and occlusion when asked), and resolves the classification.
pub fn prepare(ctx: &Arc<Context>, v: &Volume, classification: Classification) -> Result<Scene> {
    let mut profiler = Profiler::new(ctx, 2)?;
    let mut textures = Normals::new(ctx)?.prepare(v, &mut profiler)?;
    let mut passes = profiler.results()?;
    let (transfer, occlusion_tf) = match classification {
        Classification::Transfer(tf) => (tf, None),
        Classification::Features(map) => {
            let s = crate::volume::stats::stats(v, 0);
            (feature_transfer_function(&map, [s.min, s.max])?, None)
        }
        Classification::Occlusion(otf) => {
            let (visibility, neighbourhood) = parse_mapping(&otf.mapping)?;
            let p = OcclusionParams {
                radius: otf.radius,
                visibility,
                neighbourhood,
                stride: otf.effective_stride(),
                spectrum_bins: None,
            };
            let occ = Occlusion::new(ctx)?.compute(v, &p)?;
            passes.extend(occ.passes.into_iter().filter(|p| p.name == "occlusion"));
            textures.attach_occlusion(ctx, &occ.occlusion)?;
            (TransferFunction::preset("grey")?, Some(otf.table()?))
        }
    };
    Ok(Scene {
        textures,
        transfer,
        occlusion_tf,
        passes,
    })
}
