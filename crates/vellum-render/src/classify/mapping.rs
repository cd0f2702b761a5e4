//! Visibility mappings and neighbourhoods of the occlusion pass (SPEC OS2): how intensity maps to
//! the visibility M that the neighbourhood averages. Occlusion transfer-function files name their
//! mapping with the same grammar as `vellum occlusion --mapping`.

use crate::classify::transfer::TransferFunction;
use vellum_error::{Error, Result};
pub use vellum_volume::reference::occlusion::Visibility;

/// The neighbourhood and its weights (SPEC OS2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Neighbourhood {
    /// All voxels within distance R, equally weighted.
    Ball,
    /// Gaussian weights exp(−d²/2σ²), σ = R/3, over the box |d|∞ ≤ R.
    Gaussian,
}

/// Parses `--mapping ramp|truncated:T0,T1|gaussian|tf:FILE` into (visibility, neighbourhood).
/// T0 and T1 are fractions of the data range in [0, 1].
pub fn parse_mapping(s: &str) -> Result<(Visibility, Neighbourhood)> {
    let bad = || {
        Error::Invalid(format!("mapping '{s}' is unknown; expected ramp, truncated:T0,T1 (fractions of the data range), gaussian or tf:FILE.json"))
    };
    match s.split_once(':') {
        None if s == "ramp" => Ok((Visibility::Ramp, Neighbourhood::Ball)),
        None if s == "gaussian" => Ok((Visibility::Ramp, Neighbourhood::Gaussian)),
        Some(("truncated", rest)) => {
            let v: Vec<f32> = rest
                .split(',')
                .map(|x| x.trim().parse::<f32>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| bad())?;
            match v[..] {
                [t0, t1] if (0.0..=1.0).contains(&t0) && (0.0..=1.0).contains(&t1) && t0 < t1 => Ok((Visibility::Truncated { t0, t1 }, Neighbourhood::Ball)),
                _ => Err(Error::Invalid(format!("truncated ramp '{rest}' needs cut-offs 0 <= T0 < T1 <= 1 (fractions of the data range)"))),
            }
        }
        Some(("tf", path)) => {
            let tf = TransferFunction::load(std::path::Path::new(path))?;
            Ok((
                Visibility::Table(tf.table(256).iter().map(|c| c[3]).collect()),
                Neighbourhood::Ball,
            ))
        }
        _ => Err(bad()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_parsing() {
        assert_eq!(
            parse_mapping("ramp").unwrap(),
            (Visibility::Ramp, Neighbourhood::Ball)
        );
        assert_eq!(
            parse_mapping("gaussian").unwrap().1,
            Neighbourhood::Gaussian
        );
        assert_eq!(
            parse_mapping("truncated:0.1,0.5").unwrap().0,
            Visibility::Truncated { t0: 0.1, t1: 0.5 }
        );
        assert!(parse_mapping("truncated:0.5,0.1").is_err());
        assert!(parse_mapping("box").is_err());
        assert!(parse_mapping("tf:/no/such.json").is_err());
    }
}
