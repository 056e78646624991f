//! The transfer methods a display can ask for, by name (Jähne 2014 ch. 3–5).
//!
//! The method itself travels in every request and frame header as
//! [`strata_wire::TransferMethod`]; this module is the user-facing side: names, options, checks.

pub use strata_wire::TransferMethod as Transfer;

/// Names accepted by `--transfer`.
pub const NAMES: &[&str] = &["full", "depth-limited", "difference", "reprojection"];

/// Why `--transfer` and its options do not name a transfer method.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TransferError {
    /// Not one of [`NAMES`].
    #[error("unknown transfer '{0}': expected one of {names}", names = NAMES.join(", "))]
    Unknown(String),
    /// `depth-limited` without `--layers`.
    #[error("--transfer depth-limited needs --layers N (N ≥ 1)")]
    NeedsLayers,
    /// `--layers` or `--opacity-threshold` with another transfer.
    #[error("--layers and --opacity-threshold apply to --transfer depth-limited, not {0}")]
    NotDepthLimited(String),
    /// `--layers 0`.
    #[error("--layers must be at least 1")]
    NoLayers,
    /// An opacity threshold outside (0, 1].
    #[error("--opacity-threshold {0} is outside (0, 1]")]
    Threshold(f32),
}

/// The transfer method `name` with its options (`layers` and `opacity_threshold` belong to
/// `depth-limited` only).
pub fn parse(
    name: &str,
    layers: Option<u32>,
    opacity_threshold: Option<f32>,
) -> Result<Transfer, TransferError> {
    let t = match name {
        "full" => Transfer::Full,
        "depth-limited" => Transfer::DepthLimited {
            layers: layers.ok_or(TransferError::NeedsLayers)?,
            opacity_threshold,
        },
        "difference" => Transfer::Difference,
        "reprojection" => Transfer::Reprojection,
        other => return Err(TransferError::Unknown(other.to_string())),
    };
    if !matches!(t, Transfer::DepthLimited { .. })
        && (layers.is_some() || opacity_threshold.is_some())
    {
        return Err(TransferError::NotDepthLimited(name.to_string()));
    }
    if let Transfer::DepthLimited {
        layers,
        opacity_threshold,
    } = t
    {
        if layers == 0 {
            return Err(TransferError::NoLayers);
        }
        if let Some(o) = opacity_threshold
            && !(o > 0.0 && o <= 1.0)
        {
            return Err(TransferError::Threshold(o));
        }
    }
    Ok(t)
}

/// The method's name as `--transfer` spells it.
pub fn name(t: Transfer) -> &'static str {
    match t {
        Transfer::Full => "full",
        Transfer::DepthLimited { .. } => "depth-limited",
        Transfer::Difference => "difference",
        Transfer::Reprojection => "reprojection",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_options() {
        assert_eq!(parse("full", None, None), Ok(Transfer::Full));
        assert_eq!(
            parse("depth-limited", Some(6), Some(0.9)),
            Ok(Transfer::DepthLimited {
                layers: 6,
                opacity_threshold: Some(0.9)
            })
        );
        for (n, l, o, want) in [
            ("depth-limited", None, None, TransferError::NeedsLayers),
            ("depth-limited", Some(0), None, TransferError::NoLayers),
            (
                "depth-limited",
                Some(2),
                Some(1.5),
                TransferError::Threshold(1.5),
            ),
            (
                "full",
                Some(2),
                None,
                TransferError::NotDepthLimited("full".into()),
            ),
            (
                "bilateral",
                None,
                None,
                TransferError::Unknown("bilateral".into()),
            ),
            (
                "reprojection",
                Some(3),
                None,
                TransferError::NotDepthLimited("reprojection".into()),
            ),
        ] {
            assert_eq!(parse(n, l, o), Err(want), "{n} {l:?} {o:?}");
        }
        for n in ["full", "difference", "reprojection"] {
            assert_eq!(name(parse(n, None, None).unwrap()), n);
        }
    }
}
