//! A volume on the GPU as the renderers see it (issue 39): whole in core ([`VolumeTextures`]), or
//! through the brick cache ([`PagedVolume`]). The two are different types, so that nothing asks
//! at run time whether a volume in core has a cache; a renderer takes either as a [`VolumeRef`].

use crate::passes::importance::ImportanceVolume;
use crate::passes::normals::{Bricks, VolumeTextures};
use crate::passes::paging::{Paged, PagedVolume};
use vellum_gpu::Image;
use vellum_volume::geometry::Geometry;

/// A volume on the GPU, borrowed: what a renderer draws.
#[derive(Copy, Clone)]
pub enum VolumeRef<'a> {
    /// The whole volume in GPU memory.
    InCore(&'a VolumeTextures),
    /// A volume drawn through the brick cache.
    Paged(&'a PagedVolume),
}

impl<'a> From<&'a VolumeTextures> for VolumeRef<'a> {
    fn from(v: &'a VolumeTextures) -> Self {
        VolumeRef::InCore(v)
    }
}

impl<'a> From<&'a PagedVolume> for VolumeRef<'a> {
    fn from(v: &'a PagedVolume) -> Self {
        VolumeRef::Paged(v)
    }
}

impl<'a> VolumeRef<'a> {
    /// Level 0's voxels along x, y, z.
    pub fn dims(self) -> [usize; 3] {
        match self {
            VolumeRef::InCore(v) => v.dims,
            VolumeRef::Paged(p) => p.dims,
        }
    }

    /// Level 0's physical voxel size along x, y, z (millimetres for medical data).
    pub fn spacing(self) -> [f64; 3] {
        match self {
            VolumeRef::InCore(v) => v.spacing,
            VolumeRef::Paged(p) => p.spacing,
        }
    }

    /// Level 0's origin and axis directions in physical space.
    pub fn geometry(self) -> Geometry {
        match self {
            VolumeRef::InCore(v) => v.geometry,
            VolumeRef::Paged(p) => p.geometry,
        }
    }

    /// Data values that map to normalised 0 and 1.
    pub fn range(self) -> [f64; 2] {
        match self {
            VolumeRef::InCore(v) => v.range,
            VolumeRef::Paged(p) => p.range,
        }
    }

    /// The intensity the shaders sample: the volume's texture, or the pool.
    pub fn intensity(self) -> &'a Image {
        match self {
            VolumeRef::InCore(v) => &v.intensity,
            VolumeRef::Paged(p) => &p.intensity,
        }
    }

    /// The gradients the shaders sample: the volume's; none where the ray caster makes them at
    /// each sample (a volume in core whose gradients do not fit, and every bricked volume).
    pub fn gradient(self) -> Option<&'a Image> {
        match self {
            VolumeRef::InCore(v) => v.gradient.image(),
            VolumeRef::Paged(_) => None,
        }
    }

    /// The in-core table of brick ranges (one brick of the full range through the cache, whose
    /// page table carries its bricks' flags).
    pub fn bricks(self) -> &'a Bricks {
        match self {
            VolumeRef::InCore(v) => &v.bricks,
            VolumeRef::Paged(p) => &p.whole,
        }
    }

    /// The occlusion volume, which only a volume in core carries.
    pub fn occlusion(self) -> Option<&'a Image> {
        match self {
            VolumeRef::InCore(v) => v.occlusion.as_ref(),
            VolumeRef::Paged(_) => None,
        }
    }

    /// ΔD, which only a volume in core carries.
    pub fn importance(self) -> Option<&'a ImportanceVolume> {
        match self {
            VolumeRef::InCore(v) => v.importance.as_ref(),
            VolumeRef::Paged(_) => None,
        }
    }

    /// The volume's number (`VolumeTextures::id`).
    pub fn id(self) -> u64 {
        match self {
            VolumeRef::InCore(v) => v.id,
            VolumeRef::Paged(p) => p.id,
        }
    }

    /// The brick cache, for a volume drawn through it.
    pub fn paged(self) -> Option<&'a Paged> {
        match self {
            VolumeRef::InCore(_) => None,
            VolumeRef::Paged(p) => Some(&p.paged),
        }
    }

    /// The brick cache's pools of mixed channels (channels 0-3, 4-7), for a volume drawn
    /// through it that mixes some; in core the channels' own textures are sampled.
    pub(crate) fn channel_pools(self) -> Option<(&'a Image, Option<&'a Image>)> {
        match self {
            VolumeRef::InCore(_) => None,
            VolumeRef::Paged(p) => p.channels.as_ref().map(|c| (&c.image, c.image_hi.as_ref())),
        }
    }

    /// The brick cache's slots of segment indices, for a volume drawn through it beside a label
    /// volume; in core the label volume's own buffer is read.
    pub(crate) fn label_pool(self) -> Option<&'a vellum_gpu::Buffer> {
        match self {
            VolumeRef::InCore(_) => None,
            VolumeRef::Paged(p) => p.labels.as_ref(),
        }
    }

    /// The volume in core, which object-space lines and the whole-volume passes need.
    pub(crate) fn in_core(self) -> Option<&'a VolumeTextures> {
        match self {
            VolumeRef::InCore(v) => Some(v),
            VolumeRef::Paged(_) => None,
        }
    }
}
