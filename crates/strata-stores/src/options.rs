//! What configures the methods: one options struct, parsed once, read by each method.

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
    type Err = String;

    /// `auto`, `<k>x` (a multiple of the pixel count) or a number of fragments.
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("auto") {
            return Ok(PoolCapacity::Auto);
        }
        if let Some(k) = s.strip_suffix(['x', 'X']) {
            return match k.parse::<f64>() {
                Ok(k) if k > 0.0 && k.is_finite() => Ok(PoolCapacity::PerPixel(k)),
                _ => Err(format!(
                    "'{s}': expected a positive multiple of the pixel count such as 4x"
                )),
            };
        }
        match s.replace('_', "").parse::<u64>() {
            Ok(n) if n > 0 => Ok(PoolCapacity::Fragments(n)),
            _ => Err(format!(
                "'{s}': expected auto, a multiple of the pixel count (4x) or a number of fragments"
            )),
        }
    }
}

/// A memory budget for the variable k-buffer, resolved to a number of fragments per frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// A share of the frame's fragments (`50%`): the figures of seed 001 Fig. 4.5.
    SceneShare(f64),
    /// An average number of fragments per pixel, `k_avg` of seed 001 §3.2.2 (`2x`).
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
    type Err = String;

    /// `50%`, `2x`, `20MB` / `20MiB` / `1GB` / `1GiB`, or a number of fragments.
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let bad = || {
            format!(
                "'{t}': expected a share of the frame's fragments (50%), an average per pixel (2x), \
                 bytes (20MB, 16MiB) or a number of fragments"
            )
        };
        let positive = |v: f64| (v > 0.0 && v.is_finite()).then_some(v);
        if let Some(p) = t.strip_suffix('%') {
            let v = p
                .trim()
                .parse::<f64>()
                .ok()
                .and_then(positive)
                .ok_or_else(bad)?;
            return Ok(Budget::SceneShare(v / 100.0));
        }
        if let Some(k) = t.strip_suffix(['x', 'X']) {
            return Ok(Budget::PerPixel(
                k.trim()
                    .parse::<f64>()
                    .ok()
                    .and_then(positive)
                    .ok_or_else(bad)?,
            ));
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
                let v = v
                    .trim()
                    .parse::<f64>()
                    .ok()
                    .and_then(positive)
                    .ok_or_else(bad)?;
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
    /// Importance maps: periphery and depth-complexity heuristics with noise (seed 001 §3.2.2).
    #[default]
    Importance,
    /// The Optimal-K greedy oracle (seed 001 §4.2.2, Algorithm 23).
    Optimal,
}

impl std::str::FromStr for KFrom {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "importance" => Ok(KFrom::Importance),
            "optimal" => Ok(KFrom::Optimal),
            other => Err(format!("'{other}': expected importance or optimal")),
        }
    }
}

/// Parameters of the importance function of seed 001 §3.2.2:
/// `I(p) = max(0, I_per · I_d + λ (ρ − ½))`, `I_per = 1 − (‖p − o‖ / √(w² + h²))^d`,
/// `I_d = α + (1 − α) min(1, N_layers / N_limit)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceParams {
    /// `d`: how fast importance falls off towards the periphery.
    pub periphery_exponent: f64,
    /// `α`: range bias of the depth-complexity heuristic.
    pub alpha: f64,
    /// `N_limit`: the layer count that counts as full importance; `None` uses the frame's largest
    /// per-pixel fragment count ("roughly the maximum", as the seed suggests).
    pub n_limit: Option<u32>,
    /// `λ`: noise level (the seed uses 0.1).
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
    /// `A`: fragments per pixel of the fixed-array A-buffer (seed 001 uses 8 in Table 3.1).
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
    /// `L_num`: fragments per T-buffer section of TFSS (seed 002 evaluates 1 to 4).
    pub l_num: u32,
    /// TFSS: leading-zeros elimination with a Length table (seed 002 §3.3).
    pub leading_zeros: bool,
    /// Depth peeling: most layers to peel; 0 peels until a pass finds nothing.
    pub max_layers: u32,
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
        }
    }
}

impl MethodOptions {
    /// Sets one option by its command-line name (`k`, `budget`, `k-from`, `tail-blend`, …), as
    /// method specs like `kbuffer:k=8` or `vkbuffer:budget=25%:k-from=optimal` write them. A flag
    /// given without a value (`kbuffer:tail-blend`) is `true`.
    pub fn set(&mut self, key: &str, value: Option<&str>) -> Result<(), String> {
        fn num<T: std::str::FromStr>(key: &str, v: Option<&str>) -> Result<T, String> {
            let v = v.ok_or_else(|| format!("{key} needs a value ({key}=…)"))?;
            v.trim()
                .parse()
                .map_err(|_| format!("{key}={v}: not a valid number"))
        }
        fn flag(key: &str, v: Option<&str>) -> Result<bool, String> {
            match v.map(str::trim) {
                None | Some("true" | "yes" | "on" | "1") => Ok(true),
                Some("false" | "no" | "off" | "0") => Ok(false),
                Some(v) => Err(format!("{key}={v}: expected true or false")),
            }
        }
        let val = |key: &str| value.ok_or_else(|| format!("{key} needs a value ({key}=…)"));
        match key.trim() {
            "pool" => self.pool = val(key)?.parse()?,
            "array-size" | "a" => self.array_size = num(key, value)?,
            "k" => self.k = num(key, value)?,
            "tail-blend" => self.tail_blend = flag(key, value)?,
            "budget" => self.budget = val(key)?.parse()?,
            "k-from" => self.k_from = val(key)?.parse()?,
            "periphery-exponent" | "d" => self.importance.periphery_exponent = num(key, value)?,
            "alpha" => self.importance.alpha = num(key, value)?,
            "n-limit" => self.importance.n_limit = Some(num(key, value)?),
            "noise" | "lambda" => self.importance.noise = num(key, value)?,
            "seed" => self.importance.seed = num(key, value)?,
            "l-num" => self.l_num = num(key, value)?,
            "leading-zeros" => self.leading_zeros = flag(key, value)?,
            "max-layers" => self.max_layers = num(key, value)?,
            other => {
                return Err(format!(
                    "unknown option '{other}' (known: pool, array-size, k, tail-blend, budget, k-from, \
                     periphery-exponent, alpha, n-limit, noise, seed, l-num, leading-zeros, max-layers)"
                ));
            }
        }
        Ok(())
    }
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
        for bad in ["", "0%", "-1x", "MB", "lots", "0"] {
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
        assert!(o.set("k", Some("many")).unwrap_err().contains("k=many"));
        assert!(o.set("k", None).is_err());
        assert!(
            o.set("colour", Some("red"))
                .unwrap_err()
                .contains("unknown option 'colour'")
        );
    }

    #[test]
    fn k_from_parses() {
        assert_eq!("optimal".parse(), Ok(KFrom::Optimal));
        assert!("best".parse::<KFrom>().is_err());
    }
}
