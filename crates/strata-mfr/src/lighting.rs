//! Point lights and the one shader both clients use in deferred shading (Springer 2008 §7.1's
//! "unified lighting shader"), applied to normal fragments.
//!
//! A normal fragment ([`strata_raster::FragmentOutput::PackedNormal`]) holds window depth, a
//! packed eye-space normal and the object id; the object id indexes a material palette (the
//! scene's materials). [`Shader::shade_fragment`] turns one into a colour:
//!
//! ```text
//! P  = unproject(pixel centre, depth)          eye space, P⁻¹ then divide by w
//! V  = -P / |P|
//! N  = unpack(normal), flipped towards V       two-sided, like the headlight's |N·L|
//! for each light i (eye-space position Lᵢ, colour cᵢ, range rᵢ):
//!     d  = |Lᵢ - P|,  L = (Lᵢ - P) / d,  H = (L + V) / |L + V|
//!     aᵢ = 1 / (1 + d² / rᵢ²)                  distance attenuation, 1/2 at d = rᵢ
//!     D += aᵢ · cᵢ · max(N·L, 0)
//!     S += aᵢ · cᵢ · max(N·H, 0)^s · max(N·L, 0)
//! rgb = albedo · (k_a + D) + k_s · S,  alpha = albedo alpha     quantised as unorm8
//! ```
//!
//! A fragment without a normal ([`strata_core::PackedNormal::NONE`]) gets the ambient term only;
//! an unlit object keeps its flat colour. The highlight is weighted by `N·L` so that it fades
//! out where the light reaches the surface grazing, instead of being cut off: every term is
//! continuous in the normal, which bounds what packing the normal changes. The constants `k_a`, `k_s` and the integer exponent `s`
//! are a [`LightingModel`]. The exponent is applied by repeated squaring (no `powf`), so the same
//! inputs give the same bits everywhere.
//!
//! Background pixels hold no fragment and cost nothing (the seed's stencil skip), and a final
//! frame lights only the fragments that can show ([`Shader::shade_shown`]: up to each pixel's
//! first opaque fragment).
//!
//! # Cost
//!
//! The lights are kept in groups of four, one a lane (`LightLanes`), so a fragment's four lights
//! take one pass of four-wide arithmetic (square roots and divisions included) instead of four.
//! Measured on `mfr-cars` at 1280×720 with 4 lights (2-core AMD EPYC, release, CPU time of 10
//! frames less that of none): 235 ms of CPU a frame lighting one light at a time, 145 ms with
//! the lanes. Unpacking the normal (four sines and cosines) is most of what is left; tables of
//! them (2 × 2¹⁶ entries) were tried and gained nothing: they miss the cache.

use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;
use strata_core::fragment::unorm8;
use strata_core::material::Shading;
use strata_core::{DeepFrame, DeepFrameError, Fragment, Material, ObjectId, PackedNormal, Rgba8};
use strata_scene::Scene;
use wide::f32x4;

use crate::trace::{Event, LightMotion, Trace};

/// A point light in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    /// World-space position.
    pub position: Vec3,
    /// RGB intensity (1 is full white at the light).
    pub color: [f32; 3],
    /// Distance at which the light falls to half (> 0).
    pub range: f32,
}

/// The material-independent constants of the shader.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightingModel {
    /// Ambient term `k_a`, a fraction of the albedo.
    pub ambient: f32,
    /// Specular weight `k_s` (white highlights).
    pub specular: f32,
    /// Blinn-Phong exponent `s`.
    pub shininess: u32,
}

impl Default for LightingModel {
    fn default() -> Self {
        LightingModel {
            ambient: 0.15,
            specular: 0.3,
            shininess: 32,
        }
    }
}

/// Why a frame could not be shaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LightingError {
    /// A fragment carries an object id the palette does not know.
    #[error("a fragment belongs to object id {0}, which is not in the scene")]
    UnknownObject(u32),
    /// The frame does not have the shader's size.
    #[error("the frame is {found:?} pixels but the shader is for {expected:?}")]
    Size {
        /// The shader's size.
        expected: (u32, u32),
        /// The frame's.
        found: (u32, u32),
    },
    /// The shaded frame could not be built.
    #[error("the shaded frame is invalid: {0}")]
    DeepFrame(#[from] DeepFrameError),
}

/// Four lights in eye space, one a lane, ready for shading: the shader loops over groups of
/// four and computes the four lights' terms with one instruction each (SSE on x86; `wide` falls
/// back to the same IEEE operations, one lane at a time, elsewhere, so every machine gets the
/// same bits). Lanes past the last light are marked invalid and add nothing.
#[derive(Clone, Copy, Debug)]
struct LightLanes {
    x: f32x4,
    y: f32x4,
    z: f32x4,
    r: f32x4,
    g: f32x4,
    b: f32x4,
    inv_range2: f32x4,
    /// All ones in the lanes that hold a light.
    valid: f32x4,
}

impl LightLanes {
    /// `lights` (world space, at most four) moved into eye space by `view`.
    fn new(lights: &[PointLight], view: Mat4) -> LightLanes {
        let lane = |f: &dyn Fn(&PointLight) -> f32| {
            let mut a = [0.0f32; 4];
            for (slot, l) in a.iter_mut().zip(lights) {
                *slot = f(l);
            }
            f32x4::from(a)
        };
        let eye: Vec<PointLight> = lights
            .iter()
            .map(|l| PointLight {
                position: view.transform_point3(l.position),
                ..*l
            })
            .collect();
        let lane_eye = |f: &dyn Fn(&PointLight) -> f32| {
            let mut a = [0.0f32; 4];
            for (slot, l) in a.iter_mut().zip(&eye) {
                *slot = f(l);
            }
            f32x4::from(a)
        };
        LightLanes {
            x: lane_eye(&|l| l.position.x),
            y: lane_eye(&|l| l.position.y),
            z: lane_eye(&|l| l.position.z),
            r: lane(&|l| l.color[0]),
            g: lane(&|l| l.color[1]),
            b: lane(&|l| l.color[2]),
            inv_range2: lane(&|l| 1.0 / (l.range * l.range)),
            valid: lane(&|_| f32::from_bits(u32::MAX)),
        }
    }
}

/// The shader for one frame: size, projection, lights (in eye space) and material palette.
#[derive(Clone, Debug)]
pub struct Shader {
    width: u32,
    height: u32,
    inverse_projection: Mat4,
    lights: Vec<LightLanes>,
    palette: Vec<Option<Material>>,
    /// By object id: whether the material's alpha quantises to 255 (nothing behind shows).
    opaque: Vec<bool>,
    model: LightingModel,
}

impl Shader {
    /// The shader of `scene`'s materials for a `width × height` frame seen through `view` and
    /// `projection`, lit by `lights`.
    pub fn new(
        scene: &Scene,
        (width, height): (u32, u32),
        view: Mat4,
        projection: Mat4,
        lights: &[PointLight],
        model: LightingModel,
    ) -> Shader {
        let slots = scene.objects.iter().map(|o| o.id.0 as usize + 1).max();
        let mut palette = vec![None; slots.unwrap_or(0)];
        for o in &scene.objects {
            palette[o.id.0 as usize] = Some(o.material);
        }
        let opaque = palette
            .iter()
            .map(|m| m.is_some_and(|m| unorm8(m.color[3]) == u8::MAX))
            .collect();
        let lights = lights
            .chunks(4)
            .map(|group| LightLanes::new(group, view))
            .collect();
        Shader {
            width,
            height,
            inverse_projection: projection.inverse(),
            lights,
            palette,
            opaque,
            model,
        }
    }

    /// The eye-space position of a fragment at window depth `depth` in pixel `(x, y)` (row 0 on
    /// top, pixel centres at `+½`).
    #[inline]
    pub fn eye_position(&self, x: u32, y: u32, depth: f32) -> Vec3 {
        let ndc = Vec4::new(
            (x as f32 + 0.5) / self.width as f32 * 2.0 - 1.0,
            1.0 - (y as f32 + 0.5) / self.height as f32 * 2.0,
            depth * 2.0 - 1.0,
            1.0,
        );
        let p = self.inverse_projection * ndc;
        p.truncate() / p.w
    }

    /// The colour of a normal fragment of `object` at pixel `(x, y)`.
    ///
    /// # Errors
    /// When `object` is not in the palette.
    #[inline]
    pub fn shade_fragment(
        &self,
        x: u32,
        y: u32,
        fragment: &Fragment,
    ) -> Result<Rgba8, LightingError> {
        let material = self
            .palette
            .get(fragment.object.0 as usize)
            .copied()
            .flatten()
            .ok_or(LightingError::UnknownObject(fragment.object.0))?;
        if material.shading == Shading::Unlit {
            return Ok(Rgba8::from_unorm(material.color));
        }
        let p = self.eye_position(x, y, fragment.depth);
        let normal = PackedNormal::from_bits(fragment.color.to_bits()).unpack();
        Ok(self.shade(material.color, p, normal.map(Vec3::from)))
    }

    /// The shading rule of the module docs for albedo `color` at eye position `p` with unit
    /// normal `n` (`None`: ambient only). Forward and deferred shading both call this; they
    /// differ only in the normal they pass.
    #[inline]
    pub fn shade(&self, color: [f32; 4], p: Vec3, n: Option<Vec3>) -> Rgba8 {
        let m = &self.model;
        let (mut diffuse, mut specular) = (Vec3::ZERO, Vec3::ZERO);
        if let Some(n) = n {
            let v = (-p).normalize_or_zero();
            let n = if n.dot(v) < 0.0 { -n } else { n };
            let zero = f32x4::ZERO;
            let one = f32x4::ONE;
            let (px, py, pz) = (f32x4::splat(p.x), f32x4::splat(p.y), f32x4::splat(p.z));
            let (nx, ny, nz) = (f32x4::splat(n.x), f32x4::splat(n.y), f32x4::splat(n.z));
            let (vx, vy, vz) = (f32x4::splat(v.x), f32x4::splat(v.y), f32x4::splat(v.z));
            let (mut dr, mut dg, mut db) = (zero, zero, zero);
            let (mut sr, mut sg, mut sb) = (zero, zero, zero);
            for light in &self.lights {
                let (tx, ty, tz) = (light.x - px, light.y - py, light.z - pz);
                let d2 = tx * tx + ty * ty + tz * tz;
                let d = d2.sqrt();
                let (lx, ly, lz) = (tx / d, ty / d, tz / d);
                let ndl = nx * lx + ny * ly + nz * lz;
                // A light at the fragment, or behind its surface, adds nothing (and a NaN from
                // 0 / 0 is masked away).
                let lit = light.valid & d.simd_gt(zero) & ndl.simd_gt(zero);
                let a = one / (one + d2 * light.inv_range2);
                let (hx, hy, hz) = (lx + vx, ly + vy, lz + vz);
                let h2 = hx * hx + hy * hy + hz * hz;
                let h = h2.sqrt();
                let ndh = ((nx * hx + ny * hy + nz * hz) / h).max(zero);
                // H is zero (normalize_or_zero) when L and V are opposite: no highlight.
                let ndh = h2.simd_gt(zero).bitselect(ndh, zero);
                let w = lit.bitselect(a * ndl, zero);
                let spec = w * pow_u32x4(ndh, m.shininess);
                dr += light.r * w;
                dg += light.g * w;
                db += light.b * w;
                sr += light.r * spec;
                sg += light.g * spec;
                sb += light.b * spec;
            }
            diffuse = Vec3::new(dr.reduce_add(), dg.reduce_add(), db.reduce_add());
            specular = Vec3::new(sr.reduce_add(), sg.reduce_add(), sb.reduce_add());
        }
        let albedo = Vec3::new(color[0], color[1], color[2]);
        let rgb = albedo * (Vec3::splat(m.ambient) + diffuse) + specular * m.specular;
        Rgba8([
            unorm8(rgb.x),
            unorm8(rgb.y),
            unorm8(rgb.z),
            unorm8(color[3]),
        ])
    }

    /// Every fragment of the normal-fragment frame `normals` shaded; empty pixels are skipped.
    /// For a frame that is still to be composed with another (a fragment hidden now may show
    /// once a stale copy in front of it is dropped); a final frame takes [`Shader::shade_shown`].
    ///
    /// # Errors
    /// When the frame has another size or holds an object the palette does not know.
    pub fn shade_frame(&self, normals: &DeepFrame) -> Result<DeepFrame, LightingError> {
        self.check(normals)?;
        let counts: Vec<u32> = normals.counts().collect();
        self.shade_runs(normals, &counts)
    }

    /// The fragments of the final normal-fragment frame `normals` that can show, shaded: each
    /// pixel's run up to and including its first opaque fragment. A fragment's alpha is its
    /// material's, known before lighting; behind an opaque fragment the transmittance is exactly
    /// 0, so the fragments there add exactly nothing to the resolved pixel, and are neither lit
    /// nor kept. The resolved image is the same, bit for bit, as [`Shader::shade_frame`]'s.
    ///
    /// # Errors
    /// As [`Shader::shade_frame`].
    pub fn shade_shown(&self, normals: &DeepFrame) -> Result<DeepFrame, LightingError> {
        self.check(normals)?;
        let pixels = normals.width() as usize * normals.height() as usize;
        let counts: Vec<u32> = (0..pixels)
            .into_par_iter()
            .with_min_len(1024)
            .map(|p| self.shown(normals.run(p).object) as u32)
            .collect();
        self.shade_runs(normals, &counts)
    }

    /// How many fragments of a run of `objects` can show: up to and including the first opaque
    /// one (all of them when none is).
    fn shown(&self, objects: &[ObjectId]) -> usize {
        objects
            .iter()
            .position(|o| self.opaque.get(o.0 as usize).copied().unwrap_or(false))
            .map_or(objects.len(), |i| i + 1)
    }

    /// The frame's size and objects checked against the shader's.
    fn check(&self, normals: &DeepFrame) -> Result<(), LightingError> {
        let found = (normals.width(), normals.height());
        if found != (self.width, self.height) {
            return Err(LightingError::Size {
                expected: (self.width, self.height),
                found,
            });
        }
        if let Some(o) = normals
            .objects()
            .iter()
            .find(|o| self.palette.get(o.0 as usize).copied().flatten().is_none())
        {
            return Err(LightingError::UnknownObject(o.0));
        }
        Ok(())
    }

    /// The first `counts[p]` fragments of every pixel `p` of a checked frame, shaded.
    fn shade_runs(&self, normals: &DeepFrame, counts: &[u32]) -> Result<DeepFrame, LightingError> {
        let width = self.width as usize;
        Ok(DeepFrame::build(
            self.width,
            self.height,
            counts,
            |p, out| {
                let (x, y) = ((p % width) as u32, (p / width) as u32);
                let run = normals.run(p);
                out.extend(run.iter().take(counts[p] as usize).map(|f| Fragment {
                    // Every object was checked above.
                    color: self.shade_fragment(x, y, &f).unwrap_or(Rgba8([0, 0, 0, 0])),
                    ..f
                }));
            },
        )?)
    }
}

/// `x^e` lane by lane, by repeated squaring: the same bits on every machine.
#[inline]
fn pow_u32x4(mut x: f32x4, mut e: u32) -> f32x4 {
    let mut r = f32x4::ONE;
    while e > 0 {
        if e & 1 == 1 {
            r *= x;
        }
        x *= x;
        e >>= 1;
    }
    r
}

/// `x^e` by repeated squaring: the same bits on every machine.
#[cfg(test)]
fn pow_u32(mut x: f32, mut e: u32) -> f32 {
    let mut r = 1.0;
    while e > 0 {
        if e & 1 == 1 {
            r *= x;
        }
        x *= x;
        e >>= 1;
    }
    r
}

/// The point `t_ms` into a turn around a horizontal circle (in the xz plane) about `center`, one
/// turn per `period_ms`, from the circle's +x point.
fn on_circle(center: Vec3, radius: f32, period_ms: f64, t_ms: f64) -> Vec3 {
    let a = (t_ms / period_ms).fract() as f32 * std::f32::consts::TAU;
    center + Vec3::new(a.cos(), 0.0, a.sin()) * radius
}

/// A light of a snapshot: its trace id and where it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightPose {
    /// The id its `light` events give it.
    pub id: u32,
    /// The light, at its position at the snapshot's time.
    pub light: PointLight,
}

/// The `light` events of a trace, evaluated at any time: how the state authority poses lights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TraceLights {
    /// `(t_ms, id, motion, colour, range)` in trace order.
    keys: Vec<(f64, u32, LightMotion, [f32; 3], f32)>,
}

impl TraceLights {
    /// The `light` events of `trace`.
    pub fn new(trace: &Trace) -> TraceLights {
        let keys = trace
            .events()
            .iter()
            .filter_map(|e| match e.event {
                Event::Light {
                    id,
                    motion,
                    color,
                    range,
                } => Some((e.t_ms, id, motion, color, range)),
                _ => None,
            })
            .collect();
        TraceLights { keys }
    }

    /// True when the trace has no `light` events.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// Every light keyed at or before `t_ms`, by id: at its last key's position, moving linearly
    /// towards its next key's position, or on its circle.
    pub fn at(&self, t_ms: f64) -> Vec<LightPose> {
        let mut ids: Vec<u32> = self
            .keys
            .iter()
            .filter(|k| k.0 <= t_ms)
            .map(|k| k.1)
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids.into_iter()
            .filter_map(|id| self.pose(id, t_ms))
            .collect()
    }

    fn pose(&self, id: u32, t_ms: f64) -> Option<LightPose> {
        let mine: Vec<_> = self.keys.iter().filter(|k| k.1 == id).collect();
        let last = mine.iter().rposition(|k| k.0 <= t_ms)?;
        let (t0, _, motion, color, range) = *mine[last];
        let position = match motion {
            LightMotion::At(p) => match mine.get(last + 1) {
                Some(&&(t1, _, LightMotion::At(q), _, _)) if t1 > t0 => {
                    p.lerp(q, ((t_ms - t0) / (t1 - t0)) as f32)
                }
                _ => p,
            },
            LightMotion::Circle {
                center,
                radius,
                period_ms,
            } => on_circle(center, radius, period_ms, t_ms - t0),
        };
        Some(LightPose {
            id,
            light: PointLight {
                position,
                color,
                range,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_lights_appear_at_their_first_key_and_move_between_keys() {
        let trace = Trace::from_toml(
            "test",
            r#"
            [[event]]
            t_ms = 100
            light = { id = 3, position = [0.0, 1.0, 0.0], color = [1.0, 0.5, 0.25] }
            [[event]]
            t_ms = 200
            light = { id = 3, position = [2.0, 1.0, 0.0] }
            [[event]]
            t_ms = 300
            light = { id = 3, circle = { center = [0.0, 1.0, 0.0], radius = 1.0, period_ms = 400 } }
            "#,
        )
        .expect("a trace");
        let lights = TraceLights::new(&trace);
        assert!(lights.at(50.0).is_empty());
        let mid = lights.at(150.0);
        assert_eq!(mid.len(), 1);
        assert_eq!(mid[0].id, 3);
        assert_eq!(mid[0].light.position, Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(mid[0].light.color, [1.0, 0.5, 0.25]);
        // The second key gives its own colour (the default) from its time on.
        assert_eq!(lights.at(250.0)[0].light.color, [1.0; 3]);
        // A quarter turn after the circle starts.
        let q = lights.at(400.0)[0].light.position;
        assert!((q - Vec3::new(0.0, 1.0, 1.0)).length() < 1e-5, "{q}");
    }

    /// The module docs' rule, one light at a time in plain scalar code: what the four-lane
    /// shader must compute (up to rounding, which may move a channel by one step).
    fn scalar_rule(
        lights: &[PointLight],
        model: &LightingModel,
        color: [f32; 4],
        p: Vec3,
        n: Vec3,
    ) -> [f32; 3] {
        let v = (-p).normalize_or_zero();
        let n = if n.dot(v) < 0.0 { -n } else { n };
        let (mut d, mut s) = (Vec3::ZERO, Vec3::ZERO);
        for l in lights {
            let to = l.position - p;
            let dist = to.length();
            if dist <= 0.0 {
                continue;
            }
            let lv = to / dist;
            let ndl = n.dot(lv);
            if ndl <= 0.0 {
                continue;
            }
            let a = 1.0 / (1.0 + dist * dist / (l.range * l.range));
            let c = Vec3::from(l.color);
            d += c * (a * ndl);
            let h = (lv + v).normalize_or_zero();
            s += c * (a * ndl * n.dot(h).max(0.0).powi(model.shininess as i32));
        }
        let albedo = Vec3::new(color[0], color[1], color[2]);
        (albedo * (Vec3::splat(model.ambient) + d) + s * model.specular).to_array()
    }

    proptest::proptest! {
        #[test]
        fn four_lanes_compute_the_documented_rule(
            count in 0usize..=9,
            seed in proptest::array::uniform32(-3.0f32..3.0),
            n in proptest::array::uniform3(-1.0f32..1.0),
            color in proptest::array::uniform4(0.0f32..1.0),
        ) {
            let n = Vec3::from(n);
            proptest::prop_assume!(n.length() > 0.1);
            let n = n.normalize();
            let lights: Vec<PointLight> = (0..count)
                .map(|i| PointLight {
                    position: Vec3::new(seed[3 * i], seed[3 * i + 1], seed[3 * i + 2]),
                    color: [seed[27 + i % 5].abs() / 3.0, 0.5, 1.0],
                    range: 0.5 + seed[(i + 30) % 32].abs(),
                })
                .collect();
            let model = LightingModel::default();
            let shader = Shader {
                width: 1,
                height: 1,
                inverse_projection: Mat4::IDENTITY,
                lights: lights.chunks(4).map(|g| LightLanes::new(g, Mat4::IDENTITY)).collect(),
                palette: Vec::new(),
                opaque: Vec::new(),
                model,
            };
            let p = Vec3::new(0.1, -0.2, -2.0);
            let got = shader.shade(color, p, Some(n));
            let want = scalar_rule(&lights, &model, color, p, n);
            for (k, want) in want.into_iter().enumerate() {
                let (w, g) = (f32::from(unorm8(want)), f32::from(got.0[k]));
                proptest::prop_assert!((w - g).abs() <= 1.0, "channel {}: {} vs {}", k, g, w);
            }
            proptest::prop_assert_eq!(got.0[3], unorm8(color[3]));
        }
    }

    #[test]
    fn pow_by_squaring_matches_powi() {
        for e in [0, 1, 2, 7, 32] {
            let x = 0.93f32;
            assert!((pow_u32(x, e) - x.powi(e as i32)).abs() < 1e-6, "{e}");
        }
    }

    #[test]
    fn circles_turn_once_per_period() {
        let at = |t| on_circle(Vec3::new(0.0, 1.0, 0.0), 2.0, 1000.0, t);
        let q = at(250.0);
        assert!((q - Vec3::new(0.0, 1.0, 2.0)).length() < 1e-5, "{q}");
        let full = at(1000.0);
        assert!((full - Vec3::new(2.0, 1.0, 0.0)).length() < 1e-5, "{full}");
    }
}
