//! Feature maps by density range migration (SPEC FM1–FM5; Kaufman, Mueller et al., "Volume
//! Exploration Made Easy Using Feature Maps", §3–§4, in ../shared/papers/feature-maps.txt).
//!
//! A feature (an ROI) is marked not with a tag volume but by moving its density range to a
//! private interval above all other data, with its fuzzy boundary rebuilt so the boundary stays
//! where it was. Any renderer then colours it with an ordinary 1D transfer function.
//!
//! The pipeline, one module per step of §3:
//! - `roi`: the ROI from a mask volume or seeded region growing (§3.1, FM1);
//! - [`categorise`](mod@categorise): categories 1–4 (§3.2, FM2);
//! - [`migrate`](mod@migrate): the ROI range, Δ and eq. 5, the output type, and [`migrate()`] running it all
//!   (§3.3, FM3);
//! - `reconstruct`: the region grow and eq. 10 on category 1 (§3.4, FM4);
//! - [`map`]: the feature map saved beside the feature volume (§4, FM5);
//! - [`segments`](mod@segments): each segment of a label volume migrated as a feature of its own.
//!
//! Every per-voxel pass runs in parallel over x-rows with rayon; each module's doc states the
//! reading of the paper it implements where the paper leaves room.

pub mod categorise;
pub mod map;
pub mod migrate;
pub mod neighbourhood;
pub(crate) mod reconstruct;
pub(crate) mod roi;
pub mod segments;

pub use categorise::{categorise, Categories, Category, CategoryCounts};
pub use map::{parse_color, Feature, FeatureMap, Group, Node};
pub use migrate::{migrate, MigrateParams, Migration, MigrationReport, Timings};
pub use neighbourhood::Connectivity;
pub use reconstruct::{ReconstructionCounts, RegionGrow};
pub use roi::{label_volume, parse_seeds, parse_window, Roi};
pub use segments::migrate_segments;
