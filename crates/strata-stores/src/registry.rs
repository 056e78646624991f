//! Methods by name, the options each one reads, and how faithful its image is.
//!
//! [`METHODS`] is the one table: a method's name, summary, the options it reads (names of
//! [`crate::options::OPTION_NAMES`]), its [`Fidelity`] under given options, and its constructor.
//! [`check_option`] refuses an option the chosen method would ignore, naming the methods that take
//! it; the command line and method specs both go through it.

use crate::abuffer::{fixed_array, linked_list, sbuffer};
use crate::baselines::{depth_peeling, dual_depth_peeling, wboit};
use crate::kbuffer::{fixed, variable};
use crate::method::Method;
use crate::options::{KFrom, MethodOptions, PoolCapacity};
use crate::{tfss, wf};

/// How faithful a method's image is to compositing every fragment in depth order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fidelity {
    /// Keeps every fragment and composites them in depth order. (`wf` and `dual-depth-peeling`
    /// round differently and may differ from the A-buffer by one 8-bit step.)
    Exact,
    /// Keeps at most a bounded number of fragments per pixel (k, an array size, a fixed pool, a
    /// layer limit): exact where the fragments fit, and the ones it loses are counted.
    Bounded,
    /// Blends every fragment with weights instead of sorting them, and keeps no fragments.
    Approximate,
}

impl Fidelity {
    /// A short description for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Fidelity::Exact => "exact (keeps every fragment, composited in depth order)",
            Fidelity::Bounded => {
                "bounded (keeps a limited number of fragments per pixel; the ones lost are counted)"
            }
            Fidelity::Approximate => "approximate (weighted blend; keeps no fragments)",
        }
    }
}

/// A method as `--method` selects it.
#[derive(Clone, Copy, Debug)]
pub struct MethodInfo {
    /// The name it is selected by.
    pub name: &'static str,
    /// One line on what it is and where it comes from.
    pub summary: &'static str,
    /// The options it reads.
    pub options: &'static [&'static str],
    /// The per-pixel maps it computes ([`crate::Method::pixel_maps`]), by name.
    pub pixel_maps: &'static [&'static str],
    fidelity: fn(&MethodOptions) -> Fidelity,
    build: fn(&MethodOptions) -> Box<dyn Method>,
}

impl MethodInfo {
    /// A new instance configured by `options`.
    pub fn build(&self, options: &MethodOptions) -> Box<dyn Method> {
        (self.build)(options)
    }

    /// How faithful its image is when configured by `options`.
    pub fn fidelity(&self, options: &MethodOptions) -> Fidelity {
        (self.fidelity)(options)
    }

    /// True if it reads `option` when configured by `options` (the variable k-buffer reads the
    /// importance parameters only with `k-from importance`).
    pub fn reads(&self, option: &str, options: &MethodOptions) -> bool {
        self.options.contains(&option)
            && !(self.name == variable::NAME
                && options.k_from != KFrom::Importance
                && IMPORTANCE_OPTIONS.contains(&option))
            && !(self.name == variable::NAME
                && options.k_from != KFrom::Learned
                && option == "weights")
    }
}

/// The options of the variable k-buffer's importance maps (unused with `k-from optimal` and
/// `k-from analytic`).
const IMPORTANCE_OPTIONS: &[&str] = &[
    "periphery-exponent",
    "range-bias",
    "n-limit",
    "noise",
    "point-of-interest",
    "seed",
];

fn exact_with_growing_pool(o: &MethodOptions) -> Fidelity {
    if o.pool == PoolCapacity::Auto {
        Fidelity::Exact
    } else {
        Fidelity::Bounded
    }
}

fn exact_without_layer_limit(o: &MethodOptions) -> Fidelity {
    if o.max_layers == 0 {
        Fidelity::Exact
    } else {
        Fidelity::Bounded
    }
}

/// Every method, one line each.
pub const METHODS: &[MethodInfo] = &[
    MethodInfo {
        name: linked_list::NAME,
        summary: "per-pixel linked-list A-buffer: heads, node pool, allocation counter (Jähne 2014; Tsopouridis 2021, Alg. 4-6)",
        options: &["pool"],
        pixel_maps: &[],
        fidelity: exact_with_growing_pool,
        build: |o| Box::new(linked_list::LinkedListABuffer::new(o.pool)),
    },
    MethodInfo {
        name: fixed_array::NAME,
        summary: "fixed-array A-buffer: --array-size fragments per pixel, overflow counted (Tsopouridis 2021, Alg. 1-3)",
        options: &["array-size"],
        pixel_maps: &[],
        fidelity: |_| Fidelity::Bounded,
        build: |o| Box::new(fixed_array::FixedArrayABuffer::new(o)),
    },
    MethodInfo {
        name: sbuffer::NAME,
        summary: "S-buffer: counting pass, prefix sum, exactly sized contiguous regions (Vasilakis & Fudos 2012; Tsopouridis 2021, Alg. 7-12)",
        options: &[],
        pixel_maps: &[],
        fidelity: |_| Fidelity::Exact,
        build: |o| Box::new(sbuffer::SBuffer::new(o)),
    },
    MethodInfo {
        name: wf::NAME,
        summary: "weight-factor resolve over S-buffer regions, no sort (Amor et al. 2006; Lin 2007, Eq. 2-4)",
        options: &[],
        pixel_maps: &[],
        fidelity: |_| Fidelity::Exact,
        build: |o| Box::new(wf::WeightFactor::new(o)),
    },
    MethodInfo {
        name: fixed::NAME,
        summary: "k-buffer: the --k nearest fragments per pixel by insertion, --tail-blend for the rest (Tsopouridis 2021, Alg. 13-15)",
        options: &["k", "tail-blend"],
        pixel_maps: &[],
        fidelity: |_| Fidelity::Bounded,
        build: |o| Box::new(fixed::KBuffer::new(o)),
    },
    MethodInfo {
        name: variable::NAME,
        summary: "variable k-buffer: k(p) under a --budget from importance maps, --k-from optimal, analytic or learned (Tsopouridis 2021, Alg. 16-21, 23; ch. 4)",
        options: &[
            "budget",
            "k-from",
            "weights",
            "periphery-exponent",
            "range-bias",
            "n-limit",
            "noise",
            "point-of-interest",
            "seed",
        ],
        pixel_maps: &["k", "importance"],
        fidelity: |_| Fidelity::Bounded,
        build: |o| Box::new(variable::VariableKBuffer::new(o)),
    },
    MethodInfo {
        name: tfss::NAME,
        summary: "TFSS: SSA table, T-buffer sections of --l-num fragments, NSA chains, --leading-zeros (Lin 2007, ch. 3)",
        options: &["l-num", "leading-zeros", "pool"],
        pixel_maps: &[],
        fidelity: exact_with_growing_pool,
        build: |o| Box::new(tfss::Tfss::new(o)),
    },
    MethodInfo {
        name: depth_peeling::NAME,
        summary: "depth peeling, one pass per layer, --max-layers (Everitt 2001)",
        options: &["max-layers"],
        pixel_maps: &[],
        fidelity: exact_without_layer_limit,
        build: |o| Box::new(depth_peeling::DepthPeeling::new(o)),
    },
    MethodInfo {
        name: dual_depth_peeling::NAME,
        summary: "dual depth peeling, nearest and farthest layer per pass (Bavoil & Myers 2008)",
        options: &["max-layers"],
        pixel_maps: &[],
        fidelity: exact_without_layer_limit,
        build: |o| Box::new(dual_depth_peeling::DualDepthPeeling::new(o)),
    },
    MethodInfo {
        name: wboit::NAME,
        summary: "weighted blended OIT, one pass, approximate (McGuire & Bavoil 2013)",
        options: &[],
        pixel_maps: &[],
        fidelity: |_| Fidelity::Approximate,
        build: |o| Box::new(wboit::Wboit::new(o)),
    },
];

/// No method has the name asked for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown method '{name}' (known: {})", METHODS.iter().map(|m| m.name).collect::<Vec<_>>().join(", "))]
pub struct UnknownMethod {
    /// The name asked for.
    pub name: String,
}

/// The method called `name`.
pub fn find(name: &str) -> Result<&'static MethodInfo, UnknownMethod> {
    METHODS
        .iter()
        .find(|m| m.name == name)
        .ok_or_else(|| UnknownMethod {
            name: name.to_owned(),
        })
}

/// Builds the method called `name`.
pub fn create(name: &str, options: &MethodOptions) -> Result<Box<dyn Method>, UnknownMethod> {
    find(name).map(|m| m.build(options))
}

/// The names of the methods that read `option` (under some configuration).
pub fn methods_taking(option: &str) -> Vec<&'static str> {
    METHODS
        .iter()
        .filter(|m| m.options.contains(&option))
        .map(|m| m.name)
        .collect()
}

/// The names of the methods that are [`Fidelity::Exact`] under `options`.
pub fn exact_methods(options: &MethodOptions) -> Vec<&'static str> {
    METHODS
        .iter()
        .filter(|m| m.fidelity(options) == Fidelity::Exact)
        .map(|m| m.name)
        .collect()
}

/// A method was given an option it does not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "method {method}{} does not take {shown}; {}",
    if self.only_with_importance { " with k-from optimal" } else { "" },
    who_takes(&self.taken_by, self.only_with_importance)
)]
pub struct OptionNotTaken {
    /// The method.
    pub method: &'static str,
    /// The option, as the user wrote it (`--budget` on the command line, `budget` in a spec).
    pub shown: String,
    /// The methods that read it.
    pub taken_by: Vec<&'static str>,
    /// The method reads it, but only with `k-from importance`.
    pub only_with_importance: bool,
}

fn who_takes(methods: &[&str], only_with_importance: bool) -> String {
    match methods {
        _ if only_with_importance => "it is read only with k-from importance".to_owned(),
        [] => "no method takes it".to_owned(),
        [one] => format!("only {one} takes it"),
        many => format!("the methods that take it: {}", many.join(", ")),
    }
}

/// Refuses `option` (a name of [`crate::options::OPTION_NAMES`]) unless `method`, configured by
/// `options`, reads it. `shown` is how the user wrote the option, for the message.
pub fn check_option(
    method: &str,
    option: &str,
    shown: &str,
    options: &MethodOptions,
) -> Result<(), CheckError> {
    let info = find(method)?;
    if info.reads(option, options) {
        return Ok(());
    }
    Err(CheckError::NotTaken(OptionNotTaken {
        method: info.name,
        shown: shown.to_owned(),
        taken_by: methods_taking(option),
        only_with_importance: info.options.contains(&option),
    }))
}

/// Why [`check_option`] refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CheckError {
    /// No method has that name.
    #[error(transparent)]
    UnknownMethod(#[from] UnknownMethod),
    /// The method does not read the option.
    #[error(transparent)]
    NotTaken(#[from] OptionNotTaken),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_builds_under_its_own_name() {
        let options = MethodOptions::default();
        for m in METHODS {
            assert_eq!(create(m.name, &options).unwrap().name(), m.name);
        }
        let mut names: Vec<_> = METHODS.iter().map(|m| m.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), METHODS.len(), "names are unique");
    }

    #[test]
    fn every_listed_option_exists() {
        for m in METHODS {
            for o in m.options {
                assert!(crate::options::OPTION_NAMES.contains(o), "{}: {o}", m.name);
            }
        }
        for o in crate::options::OPTION_NAMES {
            assert!(!methods_taking(o).is_empty(), "{o} is read by no method");
        }
    }

    #[test]
    fn an_option_of_another_method_is_refused_naming_the_ones_that_take_it() {
        let o = MethodOptions::default();
        check_option("kbuffer", "k", "--k", &o).unwrap();
        let e = check_option("kbuffer", "budget", "--budget", &o).unwrap_err();
        assert_eq!(
            e.to_string(),
            "method kbuffer does not take --budget; only vkbuffer takes it"
        );
        let e = check_option("kbuffer", "pool", "pool", &o).unwrap_err();
        assert_eq!(
            e.to_string(),
            "method kbuffer does not take pool; the methods that take it: abuffer, tfss"
        );
        let optimal = MethodOptions {
            k_from: KFrom::Optimal,
            ..MethodOptions::default()
        };
        check_option("vkbuffer", "range-bias", "--range-bias", &o).unwrap();
        let e = check_option("vkbuffer", "range-bias", "--range-bias", &optimal).unwrap_err();
        assert_eq!(
            e.to_string(),
            "method vkbuffer with k-from optimal does not take --range-bias; it is read only with k-from importance"
        );
        assert!(matches!(
            check_option("nope", "k", "k", &o),
            Err(CheckError::UnknownMethod(_))
        ));
    }

    #[test]
    fn listed_pixel_maps_are_the_ones_computed() {
        use strata_raster::{FrameInput, Rasterizer};
        let o = MethodOptions::default();
        let search = strata_scene::SearchPath::default();
        let scene = strata_scene::open_scene("overlap", &search).unwrap();
        for m in METHODS {
            let mut method = m.build(&o);
            let input = FrameInput::from_scene(&scene, 0);
            crate::render_frame(
                method.as_mut(),
                &mut Rasterizer::default(),
                &input,
                scene.background,
            )
            .unwrap();
            let names: Vec<_> = method.pixel_maps().iter().map(|p| p.name).collect();
            assert_eq!(names, m.pixel_maps, "{}", m.name);
        }
    }

    #[test]
    fn fidelity_follows_the_options() {
        let o = MethodOptions::default();
        assert_eq!(
            exact_methods(&o),
            [
                "abuffer",
                "sbuffer",
                "wf",
                "tfss",
                "depth-peeling",
                "dual-depth-peeling"
            ]
        );
        let fixed_pool = MethodOptions {
            pool: PoolCapacity::PerPixel(4.0),
            max_layers: 3,
            ..MethodOptions::default()
        };
        assert_eq!(exact_methods(&fixed_pool), ["sbuffer", "wf"]);
        assert_eq!(find("wboit").unwrap().fidelity(&o), Fidelity::Approximate);
        assert_eq!(find("kbuffer").unwrap().fidelity(&o), Fidelity::Bounded);
    }

    #[test]
    fn unknown_method_lists_the_known_ones() {
        let err = create("kbufer", &MethodOptions::default()).err().unwrap();
        assert!(
            err.to_string()
                .starts_with("unknown method 'kbufer' (known: abuffer, abuffer-array, "),
            "{err}"
        );
    }
}
