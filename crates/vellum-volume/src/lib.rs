#![warn(missing_docs)]
//! Volumes: the voxel grid, its readers and writers, procedural phantoms and the CPU reference
//! algorithms that every GPU pass is checked against. Nothing here knows about Vulkan: the crate
//! depends on no Vulkan crate, and only `vellum-error` of ours.
//!
//! Beside the voxels: [`input`] opens any input by name, [`output`] writes files all or nothing,
//! [`team`] splits work among ranks or threads, and [`memory`] reads the process's footprint.
//!
//! Voxel order is x fastest, then y, then z, as in NRRD and NIfTI files on disk.

pub mod bricks;
pub mod chunks;
pub mod feature;
pub mod geometry;
pub mod input;
pub mod io;
pub mod labels;
pub mod lines;
pub mod memory;
pub mod normalise;
pub mod output;
pub mod phantom;
pub mod reference;
pub mod resample;
pub mod slices;
pub mod source;
pub mod stats;
pub mod stream;
pub mod team;

use vellum_error::{Error, Result};

/// The voxel types vellum reads, keeps and uploads without conversion.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VoxelType {
    /// Unsigned 8-bit.
    U8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// 32-bit float.
    F32,
}

impl VoxelType {
    /// Bytes per voxel.
    pub fn size(self) -> usize {
        match self {
            VoxelType::U8 => 1,
            VoxelType::U16 | VoxelType::I16 => 2,
            VoxelType::F32 => 4,
        }
    }

    /// The name used on the command line and in NRRD headers (`u8` → `uint8`).
    pub fn name(self) -> &'static str {
        match self {
            VoxelType::U8 => "u8",
            VoxelType::U16 => "u16",
            VoxelType::I16 => "i16",
            VoxelType::F32 => "f32",
        }
    }

    /// Parses `u8|u16|i16|f32` (the `--raw-type` values).
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "u8" | "uint8" => Ok(VoxelType::U8),
            "u16" | "uint16" => Ok(VoxelType::U16),
            "i16" | "int16" => Ok(VoxelType::I16),
            "f32" | "float" | "float32" => Ok(VoxelType::F32),
            other => Err(Error::Invalid(format!(
                "unknown voxel type '{other}'; expected one of u8, u16, i16, f32"
            ))),
        }
    }
}

/// Voxel storage, one variant per [`VoxelType`].
#[derive(Clone, Debug, PartialEq)]
pub enum VoxelData {
    /// Unsigned 8-bit voxels.
    U8(Vec<u8>),
    /// Unsigned 16-bit voxels.
    U16(Vec<u16>),
    /// Signed 16-bit voxels.
    I16(Vec<i16>),
    /// 32-bit float voxels.
    F32(Vec<f32>),
}

impl VoxelData {
    /// `n` zero voxels of type `t`.
    pub(crate) fn zeros(t: VoxelType, n: usize) -> Self {
        match t {
            VoxelType::U8 => VoxelData::U8(vec![0; n]),
            VoxelType::U16 => VoxelData::U16(vec![0; n]),
            VoxelType::I16 => VoxelData::I16(vec![0; n]),
            VoxelType::F32 => VoxelData::F32(vec![0.0; n]),
        }
    }

    /// Whether this holds `n` voxels of type `t`: a buffer a decode of that shape can reuse.
    pub(crate) fn fits(&self, t: VoxelType, n: usize) -> bool {
        self.voxel_type() == t && self.len() == n
    }

    /// Makes this a buffer of `n` voxels of type `t`: kept as it is where it [fits](Self::fits)
    /// (its old voxels are for the caller to overwrite), else `n` zeros.
    pub(crate) fn fit(&mut self, t: VoxelType, n: usize) {
        if !self.fits(t, n) {
            *self = VoxelData::zeros(t, n);
        }
    }

    /// The type of the stored voxels.
    pub fn voxel_type(&self) -> VoxelType {
        match self {
            VoxelData::U8(_) => VoxelType::U8,
            VoxelData::U16(_) => VoxelType::U16,
            VoxelData::I16(_) => VoxelType::I16,
            VoxelData::F32(_) => VoxelType::F32,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(v) => v.len(),
            VoxelData::U16(v) => v.len(),
            VoxelData::I16(v) => v.len(),
            VoxelData::F32(v) => v.len(),
        }
    }

    /// True when there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The voxels as little-endian bytes (the in-memory layout on every platform vellum targets).
    pub fn as_bytes(&self) -> &[u8] {
        match self {
            VoxelData::U8(v) => v,
            VoxelData::U16(v) => bytemuck::cast_slice(v),
            VoxelData::I16(v) => bytemuck::cast_slice(v),
            VoxelData::F32(v) => bytemuck::cast_slice(v),
        }
    }

    /// The voxels as bytes to write in place (the layout of [`VoxelData::as_bytes`]).
    pub(crate) fn as_bytes_mut(&mut self) -> &mut [u8] {
        match self {
            VoxelData::U8(v) => v,
            VoxelData::U16(v) => bytemuck::cast_slice_mut(v),
            VoxelData::I16(v) => bytemuck::cast_slice_mut(v),
            VoxelData::F32(v) => bytemuck::cast_slice_mut(v),
        }
    }

    /// Builds voxels of type `ty` from little-endian bytes. The length must be a multiple of the size.
    pub fn from_le_bytes(ty: VoxelType, bytes: &[u8]) -> Self {
        debug_assert_eq!(bytes.len() % ty.size(), 0);
        fn collect<T, const N: usize>(b: &[u8], f: fn([u8; N]) -> T) -> Vec<T> {
            b.chunks_exact(N)
                .map(|c| f(c.try_into().expect("chunk of N bytes")))
                .collect()
        }
        match ty {
            VoxelType::U8 => VoxelData::U8(bytes.to_vec()),
            VoxelType::U16 => VoxelData::U16(collect(bytes, u16::from_le_bytes)),
            VoxelType::I16 => VoxelData::I16(collect(bytes, i16::from_le_bytes)),
            VoxelType::F32 => VoxelData::F32(collect(bytes, f32::from_le_bytes)),
        }
    }

    /// Folds every voxel's value (as f64, exact) in parallel: `fold` over runs of 64 Ki voxels,
    /// each from `init()`, the runs' results joined by `reduce`. Each stored type gets its own
    /// loop over its slice, with no per-voxel test of the type or bounds check (`get_f64`'s).
    pub fn par_fold_f64<A, I, F, R>(&self, init: I, fold: F, reduce: R) -> A
    where
        A: Send,
        I: Fn() -> A + Sync + Send,
        F: Fn(A, f64) -> A + Sync + Send,
        R: Fn(A, A) -> A + Sync + Send,
    {
        use rayon::prelude::*;
        const RUN: usize = 1 << 16;
        // Generic, not `dyn`: the fold inlines into each type's loop.
        fn runs<T, A, I, F, R>(v: &[T], init: &I, fold: F, reduce: &R) -> A
        where
            T: Copy + Sync,
            A: Send,
            I: Fn() -> A + Sync,
            F: Fn(A, T) -> A + Sync,
            R: Fn(A, A) -> A + Sync,
        {
            v.par_chunks(RUN)
                .map(|run| run.iter().fold(init(), |a, &x| fold(a, x)))
                .reduce(init, reduce)
        }
        match self {
            VoxelData::U8(v) => runs(v, &init, |a, x: u8| fold(a, x as f64), &reduce),
            VoxelData::U16(v) => runs(v, &init, |a, x: u16| fold(a, x as f64), &reduce),
            VoxelData::I16(v) => runs(v, &init, |a, x: i16| fold(a, x as f64), &reduce),
            VoxelData::F32(v) => runs(v, &init, |a, x: f32| fold(a, x as f64), &reduce),
        }
    }

    /// Voxel `i` as f64 (exact for every stored type).
    #[inline]
    pub fn get_f64(&self, i: usize) -> f64 {
        match self {
            VoxelData::U8(v) => v[i] as f64,
            VoxelData::U16(v) => v[i] as f64,
            VoxelData::I16(v) => v[i] as f64,
            VoxelData::F32(v) => v[i] as f64,
        }
    }

    /// All voxels converted to f32 (exact for u8, u16, i16).
    pub fn to_f32(&self) -> Vec<f32> {
        match self {
            VoxelData::U8(v) => v.iter().map(|&x| x as f32).collect(),
            VoxelData::U16(v) => v.iter().map(|&x| x as f32).collect(),
            VoxelData::I16(v) => v.iter().map(|&x| x as f32).collect(),
            VoxelData::F32(v) => v.clone(),
        }
    }
}

/// A 3D scalar grid with physical voxel spacing.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z (millimetres for medical data, arbitrary otherwise).
    pub spacing: [f64; 3],
    /// The voxels, x fastest.
    pub data: VoxelData,
    /// Origin and directions in LPS (see `geometry`); defaults when the source says nothing.
    pub geometry: geometry::Geometry,
}

/// Largest voxel count vellum accepts from a file header before reading data (16 Gi voxels), so a
/// corrupt header cannot make us try to allocate absurd amounts of memory.
pub(crate) const MAX_VOXELS: u128 = 1 << 34;

impl Volume {
    /// Makes a volume, checking that the dims are non-zero and agree with the voxel count.
    pub fn new(dims: [usize; 3], spacing: [f64; 3], data: VoxelData) -> Result<Self> {
        check_dims(dims)?;
        let n = dims[0] * dims[1] * dims[2];
        if data.len() != n {
            return Err(Error::Invalid(format!(
                "volume of {}x{}x{} needs {n} voxels but {} were given",
                dims[0],
                dims[1],
                dims[2],
                data.len()
            )));
        }
        if spacing.iter().any(|s| !s.is_finite() || *s <= 0.0) {
            return Err(Error::Invalid(format!(
                "voxel spacing {spacing:?} is invalid; expected three positive finite numbers"
            )));
        }
        Ok(Volume {
            dims,
            spacing,
            data,
            geometry: geometry::Geometry::default(),
        })
    }

    /// The same volume placed by `g` (checked).
    pub fn with_geometry(mut self, g: geometry::Geometry) -> Result<Self> {
        g.validate()?;
        self.geometry = g;
        Ok(self)
    }

    /// Voxel type.
    pub fn voxel_type(&self) -> VoxelType {
        self.data.voxel_type()
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True when the volume has no voxels (never for a volume built by [`Volume::new`]).
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Linear index of voxel (x, y, z).
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// sha256 of the voxels as little-endian bytes, in lower-case hex.
    pub fn sha256_hex(&self) -> String {
        use sha2::{Digest, Sha256};
        let digest = Sha256::digest(self.data.as_bytes());
        digest.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// Counts NaN and infinite voxels (always 0 for integer types).
    pub(crate) fn count_non_finite(&self) -> usize {
        match &self.data {
            VoxelData::F32(v) => v.iter().filter(|x| !x.is_finite()).count(),
            _ => 0,
        }
    }

    /// Fails with [`Error::NonFinite`] when any voxel is NaN or infinite.
    pub fn check_finite(&self, what: &str) -> Result<()> {
        match self.count_non_finite() {
            0 => Ok(()),
            count => Err(Error::NonFinite {
                what: what.to_string(),
                count,
            }),
        }
    }
}

/// Checks dims for zero and absurd sizes. Device limits are checked where a device is known.
pub fn check_dims(dims: [usize; 3]) -> Result<()> {
    if dims.contains(&0) {
        return Err(Error::Invalid(format!(
            "volume dims {}x{}x{} contain a zero; expected every dimension to be at least 1",
            dims[0], dims[1], dims[2]
        )));
    }
    let n = dims.iter().map(|&d| d as u128).product::<u128>();
    if n > MAX_VOXELS {
        return Err(Error::Invalid(format!(
            "volume dims {}x{}x{} give {n} voxels; expected at most {MAX_VOXELS}",
            dims[0], dims[1], dims[2]
        )));
    }
    Ok(())
}

impl Volume {
    /// The data values [`Volume::normalised_u16`] maps to 0 and 65535: the smallest and largest.
    pub fn normalised_range(&self) -> [f64; 2] {
        let s = stats::stats(self, 0);
        [s.min, s.max]
    }

    /// The voxels mapped linearly from [min, max] to 0..=65535, with that range. This is what the
    /// renderer samples: one texture format for every voxel type, and transfer functions defined on
    /// the normalised range. A constant volume maps to 0.
    pub fn normalised_u16(&self) -> (Vec<u16>, [f64; 2]) {
        self.normalised_u16_in(self.normalised_range())
    }

    /// Copies the voxels of `src`, whose first voxel lies at `src_lo` of the grid this volume's
    /// first voxel lies at `dst_lo` of, where the two boxes overlap. Both hold one voxel type
    /// (the levels of a store do); another type copies nothing.
    pub(crate) fn paste(&mut self, src: &Volume, src_lo: [usize; 3], dst_lo: [usize; 3]) {
        let dst = self;
        let lo: [usize; 3] = std::array::from_fn(|a| src_lo[a].max(dst_lo[a]));
        let hi: [usize; 3] =
            std::array::from_fn(|a| (src_lo[a] + src.dims[a]).min(dst_lo[a] + dst.dims[a]));
        if (0..3).any(|a| lo[a] >= hi[a]) {
            return;
        }
        let w = hi[0] - lo[0];
        let (sd, dd) = (src.dims, dst.dims);
        fn rows<T: Copy>(
            s: &[T],
            d: &mut [T],
            (lo, hi, w): ([usize; 3], [usize; 3], usize),
            (src_lo, sd): ([usize; 3], [usize; 3]),
            (dst_lo, dd): ([usize; 3], [usize; 3]),
        ) {
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let si =
                        (lo[0] - src_lo[0]) + sd[0] * ((y - src_lo[1]) + sd[1] * (z - src_lo[2]));
                    let di =
                        (lo[0] - dst_lo[0]) + dd[0] * ((y - dst_lo[1]) + dd[1] * (z - dst_lo[2]));
                    d[di..di + w].copy_from_slice(&s[si..si + w]);
                }
            }
        }
        let span = (lo, hi, w);
        match (&src.data, &mut dst.data) {
            (VoxelData::U8(s), VoxelData::U8(d)) => rows(s, d, span, (src_lo, sd), (dst_lo, dd)),
            (VoxelData::U16(s), VoxelData::U16(d)) => rows(s, d, span, (src_lo, sd), (dst_lo, dd)),
            (VoxelData::I16(s), VoxelData::I16(d)) => rows(s, d, span, (src_lo, sd), (dst_lo, dd)),
            (VoxelData::F32(s), VoxelData::F32(d)) => rows(s, d, span, (src_lo, sd), (dst_lo, dd)),
            // A store's levels share one type (`Multiscale::open` checks it).
            _ => {}
        }
    }

    /// [`Volume::normalised_u16`] over a given `[lo, hi]`, such as a whole grid's range for one
    /// of its chunks (values outside it clamp).
    pub fn normalised_u16_in(&self, [lo, hi]: [f64; 2]) -> (Vec<u16>, [f64; 2]) {
        let scale = normalise::scale_of([lo, hi]);
        (self.data.normalised_par(lo, scale), [lo, hi])
    }
}
