//! What configures the methods: one options struct, parsed once, read by each method.
//!
//! Every option has one name (`k`, `budget`, `point-of-interest`, …) used both on the command
//! line (`--k`, `--budget`) and in method specs (`kbuffer:k=8`), and one parse function that
//! range-checks it ([`parse_k`], [`parse_range_bias`], …, and `FromStr` for [`PoolCapacity`],
//! [`Budget`] and [`KFrom`]). The command line's argument parser and [`MethodOptions::set`] call
//! the same functions, so both forms accept exactly the same values. Which method reads which
//! option is the registry's business ([`crate::registry::check_option`]).

/// What an option accepts, when a value is outside it: the message says what is expected, and
/// the caller adds which option and which value (`--alpha 2`, `alpha=2`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("expected {expected}")]
pub struct BadValue {
    /// What the option accepts, in words.
    pub expected: &'static str,
}

/// Why [`MethodOptions::set`] refused an option.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum OptionError {
    /// No option has this name.
    #[error("unknown option '{option}' (known: {})", OPTION_NAMES.join(", "))]
    Unknown {
        /// The name given.
        option: String,
    },
    /// The option takes a value and was given none.
    #[error("{option} needs a value ({option}=…)")]
    MissingValue {
        /// The option.
        option: &'static str,
    },
    /// The value is not one the option accepts.
    #[error("{option}={value}: {reason}")]
    BadValue {
        /// The option.
        option: &'static str,
        /// The value given.
        value: String,
        /// What it accepts.
        reason: BadValue,
    },
    /// A weights file that cannot be read or used.
    #[error("weights={path}: {reason}")]
    Weights {
        /// The file.
        path: String,
        /// Why it was refused.
        reason: String,
    },
}

/// Every option's name, as `--name` on the command line and `name=value` in a method spec.
pub const OPTION_NAMES: &[&str] = &[
    "pool",
    "array-size",
    "k",
    "tail-blend",
    "budget",
    "k-from",
    "periphery-exponent",
    "range-bias",
    "n-limit",
    "noise",
    "point-of-interest",
    "seed",
    "l-num",
    "leading-zeros",
    "max-layers",
    "weights",
];

/// The largest `k` and array size a store accepts: more than any pixel of the built-in scenes or
/// the real meshes holds, and small enough that `k × pixels` slots stay allocatable.
pub const MAX_FRAGMENTS_PER_PIXEL: u32 = 1024;

/// A whole number in `min..=max`.
fn whole(s: &str, min: u64, max: u64, expected: &'static str) -> Result<u64, BadValue> {
    match s.trim().replace('_', "").parse::<u64>() {
        Ok(n) if (min..=max).contains(&n) => Ok(n),
        _ => Err(BadValue { expected }),
    }
}

/// A finite number in `range` (which may be open at either end through `lo_open`).
fn real(s: &str, lo: f64, hi: f64, lo_open: bool, expected: &'static str) -> Result<f64, BadValue> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v <= hi && (v > lo || (!lo_open && v == lo)) => Ok(v),
        _ => Err(BadValue { expected }),
    }
}

/// `array-size`: fragments per pixel of the fixed-array A-buffer, 1 to 1024.
pub fn parse_array_size(s: &str) -> Result<u32, BadValue> {
    let n = whole(
        s,
        1,
        MAX_FRAGMENTS_PER_PIXEL.into(),
        "a whole number from 1 to 1024",
    )?;
    Ok(n as u32)
}

/// `k`: fragments per pixel of the k-buffer, 1 to 1024.
pub fn parse_k(s: &str) -> Result<u32, BadValue> {
    let n = whole(
        s,
        1,
        MAX_FRAGMENTS_PER_PIXEL.into(),
        "a whole number from 1 to 1024",
    )?;
    Ok(n as u32)
}

/// `l-num`: fragments per T-buffer section of TFSS, 1 to 64.
pub fn parse_l_num(s: &str) -> Result<u32, BadValue> {
    let n = whole(
        s,
        1,
        crate::tfss::MAX_L_NUM.into(),
        "a whole number from 1 to 64",
    )?;
    Ok(n as u32)
}

/// `max-layers`: layers depth peeling peels at most; 0 peels until nothing is left.
pub fn parse_max_layers(s: &str) -> Result<u32, BadValue> {
    let expected = "a whole number (0: until nothing is left)";
    Ok(whole(s, 0, u32::MAX.into(), expected)? as u32)
}

/// `periphery-exponent`: the importance fall-off exponent `d`, a positive number up to 64.
pub fn parse_periphery_exponent(s: &str) -> Result<f64, BadValue> {
    real(s, 0.0, 64.0, true, "a number greater than 0 and at most 64")
}

/// `range-bias`: the depth-complexity range bias `α`, in `[0, 1]`.
pub fn parse_range_bias(s: &str) -> Result<f64, BadValue> {
    real(s, 0.0, 1.0, false, "a number in [0, 1]")
}

/// `noise`: the noise level `λ`, in `[0, 1]` (the importance without noise is in `[0, 1]` too).
pub fn parse_noise(s: &str) -> Result<f64, BadValue> {
    real(s, 0.0, 1.0, false, "a number in [0, 1]")
}

/// `n-limit`: the layer count of full importance, at least 1.
pub fn parse_n_limit(s: &str) -> Result<u32, BadValue> {
    Ok(whole(s, 1, u32::MAX.into(), "a whole number of at least 1")? as u32)
}

/// `seed`: the seed of the importance noise, any whole number.
pub fn parse_seed(s: &str) -> Result<u64, BadValue> {
    whole(s, 0, u64::MAX, "a whole number")
}

/// `point-of-interest`: `x,y` as fractions of the image width and height, each in `[0, 1]`.
pub fn parse_point_of_interest(s: &str) -> Result<[f64; 2], BadValue> {
    let expected = "x,y fractions of the image, each in [0, 1], such as 0.5,0.5";
    let (x, y) = s.split_once(',').ok_or(BadValue { expected })?;
    Ok([
        real(x, 0.0, 1.0, false, expected)?,
        real(y, 0.0, 1.0, false, expected)?,
    ])
}

/// A flag's value in a method spec: none (`kbuffer:tail-blend`) is `true`.
pub fn parse_flag(s: Option<&str>) -> Result<bool, BadValue> {
    match s.map(str::trim) {
        None | Some("true" | "yes" | "on" | "1") => Ok(true),
        Some("false" | "no" | "off" | "0") => Ok(false),
        Some(_) => Err(BadValue {
            expected: "true or false",
        }),
    }
}

/// How many fragment nodes a pool-based store (the linked list) allocates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PoolCapacity {
    /// Start from a guess and, when a frame overflows, grow to fit and capture it again, so no
    /// fragment is ever dropped. The regrowth is reported. The default.
    Auto,
    /// A multiple of the pixel count (`4x`); overflowing fragments are dropped and counted.
    PerPixel(f64),
    /// An absolute number of fragments; overflowing fragments are dropped and counted.
    Fragments(u64),
}

impl std::str::FromStr for PoolCapacity {
    type Err = BadValue;

    /// `auto`, `<k>x` (a positive multiple of the pixel count) or a number of fragments.
    fn from_str(s: &str) -> Result<Self, BadValue> {
        let bad = BadValue {
            expected: "auto, a positive multiple of the pixel count (4x) or a number of fragments",
        };
        let s = s.trim();
        if s.eq_ignore_ascii_case("auto") {
            return Ok(PoolCapacity::Auto);
        }
        if let Some(k) = s.strip_suffix(['x', 'X']) {
            return match k.trim().parse::<f64>() {
                Ok(k) if k > 0.0 && k.is_finite() => Ok(PoolCapacity::PerPixel(k)),
                _ => Err(bad),
            };
        }
        match s.replace('_', "").parse::<u64>() {
            Ok(n) if n > 0 => Ok(PoolCapacity::Fragments(n)),
            _ => Err(bad),
        }
    }
}

/// A memory budget for the variable k-buffer, resolved to a number of fragments per frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// A share of the frame's fragments (`50%`): the figures of Tsopouridis 2021 Fig. 4.5.
    SceneShare(f64),
    /// An average number of fragments per pixel, `k_avg` of Tsopouridis 2021 §3.2.2 (`2x`).
    PerPixel(f64),
    /// Bytes of fragment storage (`20MB`, `16MiB`), at 12 bytes a fragment.
    Bytes(u64),
    /// A number of fragments.
    Fragments(u64),
}

/// Bytes a stored fragment takes in the region stores (depth, RGBA8, object id).
pub const FRAGMENT_BYTES: u64 = 12;

impl Budget {
    /// The budget in fragments for a frame of `pixels` pixels holding `scene_fragments` in all.
    pub fn fragments(self, pixels: u64, scene_fragments: u64) -> u64 {
        match self {
            Budget::SceneShare(s) => (scene_fragments as f64 * s).floor() as u64,
            Budget::PerPixel(k) => (pixels as f64 * k).floor() as u64,
            Budget::Bytes(b) => b / FRAGMENT_BYTES,
            Budget::Fragments(n) => n,
        }
    }
}

impl std::str::FromStr for Budget {
    type Err = BadValue;

    /// `50%` (more than 0 and at most 100 %), `2x`, `20MB` / `20MiB` / `1GB` / `1GiB`, or a
    /// number of fragments.
    fn from_str(s: &str) -> Result<Self, BadValue> {
        let t = s.trim();
        let bad = || BadValue {
            expected: "a share of the frame's fragments above 0 % and up to 100 % (50%), an \
                       average per pixel (2x), bytes (20MB, 16MiB) or a number of fragments",
        };
        let positive = |v: f64| (v > 0.0 && v.is_finite()).then_some(v);
        let number = |v: &str| v.trim().parse::<f64>().ok().and_then(positive);
        if let Some(p) = t.strip_suffix('%') {
            return match number(p) {
                Some(v) if v <= 100.0 => Ok(Budget::SceneShare(v / 100.0)),
                _ => Err(bad()),
            };
        }
        if let Some(k) = t.strip_suffix(['x', 'X']) {
            return number(k).map(Budget::PerPixel).ok_or_else(bad);
        }
        let lower = t.to_ascii_lowercase();
        for (suffix, unit) in [
            ("gib", 1u64 << 30),
            ("mib", 1 << 20),
            ("kib", 1 << 10),
            ("gb", 1_000_000_000),
            ("mb", 1_000_000),
            ("kb", 1_000),
        ] {
            if let Some(v) = lower.strip_suffix(suffix) {
                let v = number(v).ok_or_else(bad)?;
                return Ok(Budget::Bytes((v * unit as f64) as u64));
            }
        }
        match t.replace('_', "").parse::<u64>() {
            Ok(n) if n > 0 => Ok(Budget::Fragments(n)),
            _ => Err(bad()),
        }
    }
}

/// Where the variable k-buffer's per-pixel k comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum KFrom {
    /// Importance maps: periphery and depth-complexity heuristics with noise (Tsopouridis 2021 §3.2.2).
    #[default]
    Importance,
    /// The Optimal-K greedy oracle (Tsopouridis 2021 §4.2.2, Algorithm 23).
    Optimal,
    /// Water-filling an analytic error model of each pixel's layers, from sums gathered in the
    /// counting pass ([`crate::kbuffer::analytic`]): no learning, the baseline a learned k must beat.
    Analytic,
    /// A small network over per-pixel features gathered in the counting pass
    /// ([`crate::kbuffer::learned`]): by default it corrects the analytic model's error curve,
    /// which is then water-filled; the built-in weights, or [`MethodOptions::weights`].
    Learned,
}

impl std::str::FromStr for KFrom {
    type Err = BadValue;

    fn from_str(s: &str) -> Result<Self, BadValue> {
        match s.trim() {
            "importance" => Ok(KFrom::Importance),
            "optimal" => Ok(KFrom::Optimal),
            "analytic" => Ok(KFrom::Analytic),
            "learned" => Ok(KFrom::Learned),
            _ => Err(BadValue {
                expected: "importance, optimal, analytic or learned",
            }),
        }
    }
}

/// Parameters of the importance function of Tsopouridis 2021 §3.2.2:
/// `I(p) = max(0, I_per · I_d + λ (ρ − ½))`, `I_per = 1 − (‖p − o‖ / √(w² + h²))^d`,
/// `I_d = α + (1 − α) min(1, N_layers / N_limit)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceParams {
    /// `d`: how fast importance falls off towards the periphery.
    pub periphery_exponent: f64,
    /// `α`: range bias of the depth-complexity heuristic.
    pub alpha: f64,
    /// `N_limit`: the layer count that counts as full importance; `None` uses the frame's largest
    /// per-pixel fragment count ("roughly the maximum", as the thesis suggests).
    pub n_limit: Option<u32>,
    /// `λ`: noise level (the thesis uses 0.1).
    pub noise: f64,
    /// The point of interest `o` as a fraction of the image size; `[0.5, 0.5]` is the centre.
    pub point_of_interest: [f64; 2],
    /// Seed of the noise `ρ`, so frames are reproducible.
    pub seed: u64,
}

impl Default for ImportanceParams {
    fn default() -> Self {
        ImportanceParams {
            periphery_exponent: 2.0,
            alpha: 0.1,
            n_limit: None,
            noise: 0.1,
            point_of_interest: [0.5, 0.5],
            seed: 0,
        }
    }
}

/// Options shared by the methods; each reads the ones it understands.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodOptions {
    /// Node pool of the linked-list A-buffer.
    pub pool: PoolCapacity,
    /// `A`: fragments per pixel of the fixed-array A-buffer (Tsopouridis 2021 uses 8 in Table 3.1).
    pub array_size: u32,
    /// `k` of the fixed k-buffer.
    pub k: u32,
    /// k-buffer: blend the fragments that do not fit behind the k kept ones, as nvpro's OIT
    /// sample does, instead of dropping them.
    pub tail_blend: bool,
    /// Memory budget of the variable k-buffer.
    pub budget: Budget,
    /// Where the variable k-buffer's k comes from.
    pub k_from: KFrom,
    /// Importance-map parameters of the variable k-buffer.
    pub importance: ImportanceParams,
    /// `L_num`: fragments per T-buffer section of TFSS (Lin 2007 evaluates 1 to 4).
    pub l_num: u32,
    /// TFSS: leading-zeros elimination with a Length table (Lin 2007 §3.3).
    pub leading_zeros: bool,
    /// Depth peeling: most layers to peel; 0 peels until a pass finds nothing.
    pub max_layers: u32,
    /// Variable k-buffer: also gather the per-pixel features of a learned k in the counting pass
    /// ([`crate::kbuffer::features`]); off by default, so the importance-map path pays nothing.
    pub features: bool,
    /// Variable k-buffer with `--k-from learned`: the model; `None` uses the built-in weights
    /// ([`crate::kbuffer::LearnedModel::builtin`]).
    pub weights: Option<std::sync::Arc<crate::kbuffer::LearnedModel>>,
}

impl Default for MethodOptions {
    fn default() -> Self {
        MethodOptions {
            pool: PoolCapacity::Auto,
            array_size: 8,
            k: 4,
            tail_blend: false,
            budget: Budget::SceneShare(0.5),
            k_from: KFrom::Importance,
            importance: ImportanceParams::default(),
            l_num: 2,
            leading_zeros: false,
            max_layers: 0,
            features: false,
            weights: None,
        }
    }
}

impl MethodOptions {
    /// Sets one option by its name (`k`, `budget`, `k-from`, `tail-blend`, …; see
    /// [`OPTION_NAMES`]), as method specs like `kbuffer:k=8` or `vkbuffer:budget=25%:k-from=optimal`
    /// write them, checking its range as the command line does. A flag given without a value
    /// (`kbuffer:tail-blend`) is `true`. Returns the option's name (the canonical one for the
    /// short aliases `a`, `d` and `lambda`).
    pub fn set(&mut self, key: &str, value: Option<&str>) -> Result<&'static str, OptionError> {
        let option = canonical_name(key.trim()).ok_or_else(|| OptionError::Unknown {
            option: key.trim().to_owned(),
        })?;
        let bad = |reason: BadValue| OptionError::BadValue {
            option,
            value: value.unwrap_or_default().to_owned(),
            reason,
        };
        if matches!(option, "tail-blend" | "leading-zeros") {
            let on = parse_flag(value).map_err(bad)?;
            match option {
                "tail-blend" => self.tail_blend = on,
                _ => self.leading_zeros = on,
            }
            return Ok(option);
        }
        let v = value.ok_or(OptionError::MissingValue { option })?;
        if option == "weights" {
            let model = crate::kbuffer::learned::LearnedModel::read(std::path::Path::new(v))
                .map_err(|e| OptionError::Weights {
                    path: v.to_owned(),
                    reason: e.to_string(),
                })?;
            self.weights = Some(std::sync::Arc::new(model));
            return Ok(option);
        }
        let i = &mut self.importance;
        match option {
            "pool" => self.pool = v.parse().map_err(bad)?,
            "array-size" => self.array_size = parse_array_size(v).map_err(bad)?,
            "k" => self.k = parse_k(v).map_err(bad)?,
            "budget" => self.budget = v.parse().map_err(bad)?,
            "k-from" => self.k_from = v.parse().map_err(bad)?,
            "periphery-exponent" => {
                i.periphery_exponent = parse_periphery_exponent(v).map_err(bad)?
            }
            "range-bias" => i.alpha = parse_range_bias(v).map_err(bad)?,
            "n-limit" => i.n_limit = Some(parse_n_limit(v).map_err(bad)?),
            "noise" => i.noise = parse_noise(v).map_err(bad)?,
            "point-of-interest" => i.point_of_interest = parse_point_of_interest(v).map_err(bad)?,
            "seed" => i.seed = parse_seed(v).map_err(bad)?,
            "l-num" => self.l_num = parse_l_num(v).map_err(bad)?,
            _ => self.max_layers = parse_max_layers(v).map_err(bad)?,
        }
        Ok(option)
    }
}

/// The option called `key`, by its name or a short alias (`a`, `d`, `lambda`, the thesis's symbols).
fn canonical_name(key: &str) -> Option<&'static str> {
    let key = match key {
        "a" => "array-size",
        "d" => "periphery-exponent",
        "lambda" => "noise",
        other => other,
    };
    OPTION_NAMES.iter().copied().find(|&n| n == key)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pool_capacity_parses() {
        assert_eq!("auto".parse(), Ok(PoolCapacity::Auto));
        assert_eq!("4x".parse(), Ok(PoolCapacity::PerPixel(4.0)));
        assert_eq!("2.5X".parse(), Ok(PoolCapacity::PerPixel(2.5)));
        assert_eq!("1_000_000".parse(), Ok(PoolCapacity::Fragments(1_000_000)));
        assert!("0".parse::<PoolCapacity>().is_err());
        assert!("-2x".parse::<PoolCapacity>().is_err());
        assert!("lots".parse::<PoolCapacity>().is_err());
    }

    #[test]
    fn budget_parses_and_resolves() {
        assert_eq!("50%".parse(), Ok(Budget::SceneShare(0.5)));
        assert_eq!("2x".parse(), Ok(Budget::PerPixel(2.0)));
        assert_eq!("20MB".parse(), Ok(Budget::Bytes(20_000_000)));
        assert_eq!("16 MiB".parse(), Ok(Budget::Bytes(16 << 20)));
        assert_eq!("1000".parse(), Ok(Budget::Fragments(1000)));
        assert_eq!("100%".parse(), Ok(Budget::SceneShare(1.0)));
        for bad in ["", "0%", "100.5%", "-1x", "MB", "lots", "0"] {
            assert!(bad.parse::<Budget>().is_err(), "{bad:?}");
        }
        assert_eq!(Budget::SceneShare(0.25).fragments(100, 1000), 250);
        assert_eq!(Budget::PerPixel(2.0).fragments(100, 1000), 200);
        assert_eq!(Budget::Bytes(1200).fragments(100, 1000), 100);
    }

    #[test]
    fn options_set_by_name() {
        let mut o = MethodOptions::default();
        o.set("k", Some("8")).unwrap();
        o.set("budget", Some("25%")).unwrap();
        o.set("k-from", Some("optimal")).unwrap();
        o.set("tail-blend", None).unwrap();
        o.set("leading-zeros", Some("false")).unwrap();
        assert_eq!(
            (o.k, o.budget, o.k_from, o.tail_blend, o.leading_zeros),
            (8, Budget::SceneShare(0.25), KFrom::Optimal, true, false)
        );
        let err = |o: &mut MethodOptions, k, v| o.set(k, v).unwrap_err().to_string();
        assert_eq!(
            err(&mut o, "k", Some("many")),
            "k=many: expected a whole number from 1 to 1024"
        );
        assert_eq!(err(&mut o, "k", None), "k needs a value (k=…)");
        assert!(
            err(&mut o, "colour", Some("red")).starts_with("unknown option 'colour' (known: pool,")
        );
        assert_eq!(o.set("lambda", Some("0.5")), Ok("noise"));
        assert_eq!(o.importance.noise, 0.5);
        o.set("point-of-interest", Some("0.25, 1")).unwrap();
        assert_eq!(o.importance.point_of_interest, [0.25, 1.0]);
    }

    /// Every range the help promises is checked, with the value and the option in the message.
    #[test]
    fn out_of_range_values_are_refused() {
        let mut o = MethodOptions::default();
        for (key, value) in [
            ("range-bias", "2"),
            ("range-bias", "-0.1"),
            ("range-bias", "NaN"),
            ("noise", "-1"),
            ("noise", "inf"),
            ("point-of-interest", "5,5"),
            ("point-of-interest", "0.5"),
            ("point-of-interest", "0.5,-0.5"),
            ("n-limit", "0"),
            ("periphery-exponent", "0"),
            ("periphery-exponent", "-2"),
            ("k", "0"),
            ("k", "1025"),
            ("array-size", "0"),
            ("l-num", "65"),
            ("max-layers", "-1"),
            ("budget", "150%"),
            ("budget", "0x"),
            ("pool", "0"),
            ("k-from", "best"),
            ("tail-blend", "maybe"),
        ] {
            let e = o.set(key, Some(value)).unwrap_err();
            assert!(
                matches!(&e, OptionError::BadValue { option, value: v, .. } if *option == key && v == value),
                "{key}={value}: {e}"
            );
            assert!(
                e.to_string()
                    .starts_with(&format!("{key}={value}: expected ")),
                "{e}"
            );
        }
        assert_eq!(
            o,
            MethodOptions::default(),
            "a refused value changes nothing"
        );
        for (key, value) in [
            ("range-bias", "0"),
            ("range-bias", "1"),
            ("noise", "0"),
            ("k", "1024"),
            ("budget", "100%"),
        ] {
            o.set(key, Some(value)).unwrap();
        }
    }

    #[test]
    fn k_from_parses() {
        assert_eq!("optimal".parse(), Ok(KFrom::Optimal));
        assert!("best".parse::<KFrom>().is_err());
    }
}
