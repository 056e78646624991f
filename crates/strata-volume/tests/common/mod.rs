#![allow(dead_code)] // each test binary uses a part of it
//! What the volume tests share: the unit box, a ray through it, transfer functions (a uniform
//! white medium; one with a clear, a soft and a dense range), and the interactive well path and
//! glass tube of the scenes.

use glam::Vec3;
use strata_volume::cast::{Ray, VolumeBox};
use strata_volume::geometry::{Glass, Shape, Solid, well_path};
use strata_volume::transfer::{TfPoint, TransferFunction};

/// The volume's box: the unit cube about the origin.
pub(crate) const UNIT_BOX: VolumeBox = VolumeBox {
    min: Vec3::splat(-0.5),
    max: Vec3::splat(0.5),
};

/// A white medium of unit opacity `alpha` at every density.
pub(crate) fn uniform(alpha: f32) -> TransferFunction {
    TransferFunction::new(
        vec![TfPoint {
            value: 0.0,
            color: [1.0; 3],
            alpha,
        }],
        1.0,
    )
    .expect("valid")
}

/// A ray down the z axis entering the unit box at t = 2.5 and leaving it at t = 3.5.
pub(crate) fn down_z() -> Ray {
    Ray {
        origin: Vec3::new(0.1, -0.2, 3.0),
        dir: Vec3::NEG_Z,
    }
}

/// The interactive well path of the test scenes: a red tube bending down through the volume.
pub(crate) fn well() -> Vec<Solid> {
    well_path(
        &[
            Vec3::new(-0.2, 0.9, 0.1),
            Vec3::new(-0.1, 0.1, 0.0),
            Vec3::new(0.3, -0.3, 0.2),
            Vec3::new(0.7, -0.4, 0.3),
        ],
        0.05,
        [0.9, 0.2, 0.1],
    )
}

/// The interactive translucent yellow tube beside the path.
pub(crate) fn glass_tube() -> Glass {
    Glass {
        shape: Shape::Tube {
            a: Vec3::new(-0.4, -0.3, -0.4),
            b: Vec3::new(0.1, 0.4, 0.5),
            radius: 0.12,
        },
        color: [0.9, 0.8, 0.2],
        alpha: 0.4,
    }
}

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
