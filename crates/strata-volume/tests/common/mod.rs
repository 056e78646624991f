//! What the volume tests share: a transfer function with a clear, a soft and a dense range.

use strata_volume::transfer::{TfPoint, TransferFunction};

/// Clear below 0.1, soft blue-orange up to 0.5, nearly opaque white at 0.9.
pub(crate) fn ramp() -> TransferFunction {
    TransferFunction::new(
        vec![
            TfPoint {
                value: 0.1,
                color: [0.2, 0.3, 0.8],
                alpha: 0.0,
            },
            TfPoint {
                value: 0.5,
                color: [0.9, 0.6, 0.4],
                alpha: 0.5,
            },
            TfPoint {
                value: 0.9,
                color: [1.0, 1.0, 0.9],
                alpha: 0.95,
            },
        ],
        0.2,
    )
    .expect("valid")
}
