//! `vellum migrate` and `vellum features` (placeholder until the feature-map work lands).

use anyhow::Result;
use clap::Args;

#[derive(Args)]
pub struct MigrateArgs {}

#[derive(Args)]
pub struct FeaturesArgs {}

pub fn migrate(_args: &MigrateArgs) -> Result<()> {
    anyhow::bail!("feature migration is not implemented yet")
}

pub fn print_tree(_args: &FeaturesArgs) -> Result<()> {
    anyhow::bail!("feature maps are not implemented yet")
}
