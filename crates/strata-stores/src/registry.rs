//! Methods by name, and the options that configure them.

use crate::abuffer::linked_list::LinkedListABuffer;
use crate::method::Method;
use crate::options::MethodOptions;

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
    fn unknown_method_lists_the_known_ones() {
        let err = create("kbufer", &MethodOptions::default()).err().unwrap();
        assert_eq!(err.to_string(), "unknown method 'kbufer' (known: abuffer)");
    }
}
