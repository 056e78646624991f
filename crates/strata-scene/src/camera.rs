//! The camera: OpenGL conventions, right-handed (strata's shared conventions).
//!
//! `view = look_at_rh(eye, target, up)`, `projection = perspective_rh_gl(fovy, width/height, near,
//! far)`: clip-space z runs from `-w` (near) to `+w` (far), window depth is `0.5 * z_ndc + 0.5`.

use glam::{Mat4, Vec3};

/// A perspective camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world space.
    pub eye: Vec3,
    /// The point looked at.
    pub target: Vec3,
    /// Up direction (need not be orthogonal to the view direction, must not be parallel).
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180).
    pub fovy_deg: f32,
    /// Near plane distance, > 0.
    pub near: f32,
    /// Far plane distance, > near.
    pub far: f32,
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            eye: Vec3::new(0.0, 0.0, 1.6),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 45.0,
            near: 0.01,
            far: 100.0,
        }
    }
}

/// Why a camera cannot be used: the scene-file key at fault and what is wrong with it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CameraError {
    /// The key, as a scene file names it (`camera.up`).
    pub key: &'static str,
    /// What is wrong, e.g. "is zero or parallel to the viewing direction".
    pub message: String,
}

impl std::fmt::Display for CameraError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

impl std::error::Error for CameraError {}

impl Camera {
    /// Checks the rules of a scene file's `[camera]` table (docs/scene-format.md): finite
    /// vectors, a target apart from the eye, an up not parallel to the view, `fovy_deg` in
    /// (0, 180), `0 < near < far`, both finite. Every camera strata renders passes this, whether
    /// it comes from a file or from the viewer.
    pub fn check(&self) -> Result<(), CameraError> {
        let fail = |key, message: String| Err(CameraError { key, message });
        for (key, v) in [
            ("camera.eye", self.eye),
            ("camera.target", self.target),
            ("camera.up", self.up),
        ] {
            if let Some(c) = v.to_array().iter().find(|c| !c.is_finite()) {
                return fail(key, format!("{c} is not a finite number"));
            }
        }
        let dir = self.target - self.eye;
        if dir.length_squared() == 0.0 {
            return fail(
                "camera.target",
                "equals camera.eye; the camera must look somewhere".into(),
            );
        }
        if self.up.cross(dir).length_squared()
            <= 1e-12 * self.up.length_squared() * dir.length_squared()
        {
            return fail(
                "camera.up",
                "is zero or parallel to the viewing direction".into(),
            );
        }
        if !(self.fovy_deg > 0.0 && self.fovy_deg < 180.0) {
            return fail(
                "camera.fovy_deg",
                format!("{} is outside (0, 180) degrees", self.fovy_deg),
            );
        }
        if !(self.near > 0.0 && self.near.is_finite()) {
            return fail(
                "camera.near",
                format!("{} must be a finite distance greater than 0", self.near),
            );
        }
        if !(self.far > self.near && self.far.is_finite()) {
            return fail(
                "camera.far",
                format!(
                    "{} must be finite and greater than near ({})",
                    self.far, self.near
                ),
            );
        }
        Ok(())
    }

    /// World → eye space.
    pub fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, self.up)
    }

    /// Eye → clip space for an image of `width` × `height` pixels.
    pub fn projection(&self, width: u32, height: u32) -> Mat4 {
        Mat4::perspective_rh_gl(
            self.fovy_deg.to_radians(),
            width as f32 / height as f32,
            self.near,
            self.far,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

    #[test]
    fn gl_depth_range_maps_near_to_minus_one_and_far_to_one() {
        let cam = Camera::default();
        let p = cam.projection(1280, 720) * cam.view();
        let near = p * Vec4::new(0.0, 0.0, cam.eye.z - cam.near, 1.0);
        let far = p * Vec4::new(0.0, 0.0, cam.eye.z - cam.far, 1.0);
        assert!((near.z / near.w + 1.0).abs() < 1e-4);
        assert!((far.z / far.w - 1.0).abs() < 1e-4);
        // The target lies on the optical axis.
        let t = p * Vec4::new(0.0, 0.0, 0.0, 1.0);
        assert!(t.x.abs() < 1e-6 && t.y.abs() < 1e-6);
    }

    #[test]
    fn check_names_the_key_at_fault() {
        assert_eq!(Camera::default().check(), Ok(()));
        let bad = |f: fn(&mut Camera)| {
            let mut c = Camera::default();
            f(&mut c);
            c.check().map_err(|e| e.key)
        };
        assert_eq!(bad(|c| c.eye.x = f32::NAN), Err("camera.eye"));
        assert_eq!(bad(|c| c.target = c.eye), Err("camera.target"));
        assert_eq!(bad(|c| c.up = Vec3::Z), Err("camera.up"));
        assert_eq!(bad(|c| c.up = Vec3::ZERO), Err("camera.up"));
        assert_eq!(bad(|c| c.fovy_deg = 180.0), Err("camera.fovy_deg"));
        assert_eq!(bad(|c| c.near = 0.0), Err("camera.near"));
        assert_eq!(bad(|c| c.far = c.near), Err("camera.far"));
        assert_eq!(bad(|c| c.far = f32::INFINITY), Err("camera.far"));
    }

    #[test]
    fn fovy_spans_the_image_height() {
        let cam = Camera::default();
        let p = cam.projection(200, 100) * cam.view();
        // A point at the top edge of the frustum at distance 1.6.
        let h = 1.6 * (22.5f32).to_radians().tan();
        let c = p * Vec4::new(0.0, h, 0.0, 1.0);
        assert!((c.y / c.w - 1.0).abs() < 1e-5);
        // Aspect 2: the same offset along x reaches half the width.
        let c = p * Vec4::new(h, 0.0, 0.0, 1.0);
        assert!((c.x / c.w - 0.5).abs() < 1e-5);
    }
}
