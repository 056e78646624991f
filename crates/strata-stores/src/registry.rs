//! Methods by name, and the options that configure them.

use crate::abuffer::linked_list::LinkedListABuffer;
use crate::method::Method;

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

/// Options shared by the methods; each reads the ones it understands.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodOptions {
    /// Node pool capacity of the linked-list A-buffer.
    pub pool: PoolCapacity,
}

impl Default for MethodOptions {
    fn default() -> Self {
        MethodOptions {
            pool: PoolCapacity::Auto,
        }
    }
}

/// Every method: name and one line on what it is.
pub const METHODS: &[(&str, &str)] = &[(
    "abuffer",
    "per-pixel linked-list A-buffer: head per pixel, node pool, allocation counter (seed 000 §2, seed 001 Alg. 4-6)",
)];

/// No method has the name asked for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown method '{name}' (known: {})", METHODS.iter().map(|m| m.0).collect::<Vec<_>>().join(", "))]
pub struct UnknownMethod {
    /// The name asked for.
    pub name: String,
}

/// Builds the method called `name`.
pub fn create(name: &str, options: &MethodOptions) -> Result<Box<dyn Method>, UnknownMethod> {
    match name {
        "abuffer" => Ok(Box::new(LinkedListABuffer::new(options.pool))),
        _ => Err(UnknownMethod {
            name: name.to_owned(),
        }),
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
    fn unknown_method_lists_the_known_ones() {
        let err = create("kbufer", &MethodOptions::default()).err().unwrap();
        assert_eq!(err.to_string(), "unknown method 'kbufer' (known: abuffer)");
    }
}
