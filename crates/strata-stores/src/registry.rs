//! Methods by name, and the options that configure them.

use crate::abuffer::{fixed_array, linked_list, sbuffer};
use crate::baselines::{depth_peeling, dual_depth_peeling, wboit};
use crate::kbuffer::{fixed, variable};
use crate::method::Method;
use crate::options::MethodOptions;
use crate::{tfss, wf};

/// A method as `--method` selects it.
#[derive(Clone, Copy, Debug)]
pub struct MethodInfo {
    /// The name it is selected by.
    pub name: &'static str,
    /// One line on what it is and where it comes from.
    pub summary: &'static str,
    build: fn(&MethodOptions) -> Box<dyn Method>,
}

impl MethodInfo {
    /// A new instance configured by `options`.
    pub fn build(&self, options: &MethodOptions) -> Box<dyn Method> {
        (self.build)(options)
    }
}

/// Every method, one line each.
pub const METHODS: &[MethodInfo] = &[
    MethodInfo {
        name: linked_list::NAME,
        summary: "per-pixel linked-list A-buffer: heads, node pool, allocation counter (seed 000 §2, seed 001 Alg. 4-6)",
        build: |o| Box::new(linked_list::LinkedListABuffer::new(o.pool)),
    },
    MethodInfo {
        name: fixed_array::NAME,
        summary: "fixed-array A-buffer: --array-size fragments per pixel, overflow counted (seed 001 Alg. 1-3)",
        build: |o| Box::new(fixed_array::FixedArrayABuffer::new(o)),
    },
    MethodInfo {
        name: sbuffer::NAME,
        summary: "S-buffer: counting pass, prefix sum, exactly sized contiguous regions (seed 001 Alg. 7-12)",
        build: |o| Box::new(sbuffer::SBuffer::new(o)),
    },
    MethodInfo {
        name: wf::NAME,
        summary: "weight-factor resolve over S-buffer regions, no sort (seed 002 §2.5.2, Eq. 2-4)",
        build: |o| Box::new(wf::WeightFactor::new(o)),
    },
    MethodInfo {
        name: fixed::NAME,
        summary: "k-buffer: the --k nearest fragments per pixel by insertion, --tail-blend for the rest (seed 001 Alg. 13-15)",
        build: |o| Box::new(fixed::KBuffer::new(o)),
    },
    MethodInfo {
        name: variable::NAME,
        summary: "variable k-buffer: k(p) under a --budget from importance maps or --k-from optimal (seed 001 Alg. 16-21, 23)",
        build: |o| Box::new(variable::VariableKBuffer::new(o)),
    },
    MethodInfo {
        name: tfss::NAME,
        summary: "TFSS: SSA table, T-buffer sections of --l-num fragments, NSA chains, --leading-zeros (seed 002 ch. 3)",
        build: |o| Box::new(tfss::Tfss::new(o)),
    },
    MethodInfo {
        name: depth_peeling::NAME,
        summary: "depth peeling, one pass per layer, --max-layers (Everitt 2001)",
        build: |o| Box::new(depth_peeling::DepthPeeling::new(o)),
    },
    MethodInfo {
        name: dual_depth_peeling::NAME,
        summary: "dual depth peeling, nearest and farthest layer per pass (Bavoil & Myers 2008)",
        build: |o| Box::new(dual_depth_peeling::DualDepthPeeling::new(o)),
    },
    MethodInfo {
        name: wboit::NAME,
        summary: "weighted blended OIT, one pass, approximate (McGuire & Bavoil 2013)",
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

/// Builds the method called `name`.
pub fn create(name: &str, options: &MethodOptions) -> Result<Box<dyn Method>, UnknownMethod> {
    METHODS
        .iter()
        .find(|m| m.name == name)
        .map(|m| m.build(options))
        .ok_or_else(|| UnknownMethod {
            name: name.to_owned(),
        })
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
    fn unknown_method_lists_the_known_ones() {
        let err = create("kbufer", &MethodOptions::default()).err().unwrap();
        assert!(
            err.to_string()
                .starts_with("unknown method 'kbufer' (known: abuffer, abuffer-array, "),
            "{err}"
        );
    }
}
