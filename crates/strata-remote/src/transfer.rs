//! The transfer methods a display can ask for, by name (seed 000 ch. 3–5).
//!
//! The method itself travels in every request and frame header as
//! [`strata_wire::TransferMethod`]; this module is the user-facing side: names, options, checks.

pub use strata_wire::TransferMethod as Transfer;

/// Names accepted by `--transfer`.
pub const NAMES: &[&str] = &["full", "depth-limited", "difference", "reprojection"];

/// The transfer method `name` with its options (`layers` and `opacity_threshold` belong to
/// `depth-limited` only), or a message saying what is wrong.
pub fn parse(
    name: &str,
    layers: Option<u32>,
    opacity_threshold: Option<f32>,
) -> Result<Transfer, String> {
    let t = match name {
        "full" => Transfer::Full,
        "depth-limited" => Transfer::DepthLimited {
            layers: layers.ok_or("--transfer depth-limited needs --layers N (N ≥ 1)")?,
            opacity_threshold,
        },
        "difference" => Transfer::Difference,
        "reprojection" => Transfer::Reprojection,
        other => {
            return Err(format!(
                "unknown transfer '{other}': expected one of {}",
                NAMES.join(", ")
            ));
        }
    };
    if !matches!(t, Transfer::DepthLimited { .. })
        && (layers.is_some() || opacity_threshold.is_some())
    {
        return Err(format!(
            "--layers and --opacity-threshold apply to --transfer depth-limited, not {name}"
        ));
    }
    if let Transfer::DepthLimited {
        layers,
        opacity_threshold,
    } = t
    {
        if layers == 0 {
            return Err("--layers must be at least 1".into());
        }
        if let Some(o) = opacity_threshold
            && !(o > 0.0 && o <= 1.0)
        {
            return Err(format!("--opacity-threshold {o} is outside (0, 1]"));
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
        for (n, l, o) in [
            ("depth-limited", None, None),
            ("depth-limited", Some(0), None),
            ("depth-limited", Some(2), Some(1.5)),
            ("full", Some(2), None),
            ("bilateral", None, None),
            ("reprojection", Some(3), None),
        ] {
            assert!(parse(n, l, o).is_err(), "{n} {l:?} {o:?}");
        }
        for n in ["full", "difference", "reprojection"] {
            assert_eq!(name(parse(n, None, None).unwrap()), n);
        }
    }
}
