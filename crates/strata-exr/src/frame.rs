//! strata's DeepFrames as deep images and back: channels, the depth mapping and exactness.
//!
//! # Channels
//!
//! | channel        | type          | value per sample                                        |
//! |----------------|---------------|---------------------------------------------------------|
//! | `R`, `G`, `B`  | HALF or FLOAT | premultiplied colour, `c/255 · a/255`                   |
//! | `A`            | HALF or FLOAT | alpha, `a/255`                                          |
//! | `Z`            | FLOAT         | distance from the eye along the view direction          |
//! | `ZBack`        | FLOAT         | optional, `= Z` (strata's fragments are points)         |
//! | `objectid`     | UINT          | the object that made the fragment (deep-ID name)        |
//! | `strata.depth` | FLOAT         | optional, the window depth `d` itself, for exactness    |
//!
//! # Depth mapping
//!
//! strata's cameras are OpenGL perspective cameras with clip planes `n < f`. A fragment's window
//! depth `d ∈ [0, 1]` maps to normalised device depth `z_ndc = 2d − 1`, and to the positive
//! eye-space distance along the view direction (what OpenEXR calls `Z`) by
//!
//! ```text
//! Z = 2 f n / ((f + n) − z_ndc (f − n))        d = ((f + n − 2 f n / Z) / (f − n) + 1) / 2
//! ```
//!
//! both evaluated in `f64` and rounded once to `f32`. `n` and `f` are stored as the `double`
//! attributes `strata.near` and `strata.far`; when the camera is known, its matrices are stored
//! too, as OpenEXR's standard `worldToCamera` and `worldToNDC` (`m44f`).
//!
//! # Exactness
//!
//! `Z` alone cannot always give back the exact `f32` depth: near the near plane `Z ≈ n (1 + d)`,
//! so every `d` below about `2^-24` (and, more generally, depths closer together than one `f32`
//! step of `Z`) maps to the same `Z`. Each `Z` is inverted to a depth that maps back to it, which
//! recovers the original for the depths real scenes produce, but not for all. So strata also
//! writes the window depth as the `FLOAT` channel `strata.depth` (on by default): reading uses it
//! whenever it is consistent with `Z` (so a tool that edited `Z` is not overridden) and falls back
//! to inverting `Z` otherwise. With it, DeepFrame → file → DeepFrame is bit-exact.
//!
//! Colour: `a8 = round(A·255)` and, when `a8 > 0`, `c8 = round(C/A·255)`. `FLOAT` channels give
//! back every 8-bit colour exactly; so do `HALF` channels (their 11 significant bits keep
//! `C/A·255` within 0.25 of the integer; the tests check every colour value with every non-zero
//! alpha). A fragment with `a8 = 0` carries no colour in premultiplied form and comes back black.

use strata_core::{DeepFrame, Fragment, ObjectId, Rgba8};

use crate::error::{ExrError, Result};
use crate::image::{Attribute, Box2i, Channel, Column, DeepImage, SampleType};

/// The name of the object-id channel (the OpenEXR deep-ID specification's name for an object
/// identifier). Reading also accepts `id`.
pub const OBJECT_ID_CHANNEL: &str = "objectid";
/// The name of the exact window-depth channel.
pub const WINDOW_DEPTH_CHANNEL: &str = "strata.depth";
const NEAR_ATTRIBUTE: &str = "strata.near";
const FAR_ATTRIBUTE: &str = "strata.far";

/// A GL perspective camera's clip planes: the map between window depth and `Z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthMapping {
    /// Near plane distance, > 0.
    pub near: f64,
    /// Far plane distance, > near.
    pub far: f64,
}

impl DepthMapping {
    /// A mapping for clip planes `0 < near < far`, both finite.
    ///
    /// # Errors
    /// [`ExrError::Frame`] if the planes are not ordered positive finite numbers.
    pub fn new(near: f64, far: f64) -> Result<Self> {
        if !(near.is_finite() && far.is_finite() && near > 0.0 && far > near) {
            return Err(ExrError::Frame(format!(
                "clip planes near = {near}, far = {far} must satisfy 0 < near < far"
            )));
        }
        Ok(DepthMapping { near, far })
    }

    /// `Z` (eye distance) of window depth `d`.
    pub fn z_from_depth(&self, d: f32) -> f32 {
        let (n, f) = (self.near, self.far);
        let z_ndc = 2.0 * f64::from(d) - 1.0;
        (2.0 * f * n / ((f + n) - z_ndc * (f - n))) as f32
    }

    /// The window depth whose `Z` is `z`: the `f64` inverse rounded to `f32`, then nudged by up
    /// to a few `f32` steps to one that maps back to `z` exactly when there is one; clamped to
    /// `[0, 1]`.
    pub fn depth_from_z(&self, z: f32) -> f32 {
        let (n, f) = (self.near, self.far);
        let z_ndc = ((f + n) - 2.0 * f * n / f64::from(z)) / (f - n);
        let guess = clamp_depth(((z_ndc + 1.0) / 2.0) as f32);
        if self.z_from_depth(guess).to_bits() == z.to_bits() {
            return guess;
        }
        for step in 1..=4u32 {
            for candidate in [
                f32::from_bits(guess.to_bits().saturating_add(step)),
                f32::from_bits(guess.to_bits().saturating_sub(step)),
            ] {
                let candidate = clamp_depth(candidate);
                if self.z_from_depth(candidate).to_bits() == z.to_bits() {
                    return candidate;
                }
            }
        }
        guess
    }

    /// The mapping stored in an image's `strata.near`/`strata.far` attributes.
    pub fn from_attributes(image: &DeepImage) -> Option<Self> {
        let near = image.attribute(NEAR_ATTRIBUTE)?.as_double()?;
        let far = image.attribute(FAR_ATTRIBUTE)?.as_double()?;
        DepthMapping::new(near, far).ok()
    }
}

fn clamp_depth(d: f32) -> f32 {
    if d.is_nan() || d <= 0.0 {
        0.0
    } else {
        d.min(1.0)
    }
}

/// A camera's matrices, column-major as OpenGL and glam's `to_cols_array` lay them out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraMatrices {
    /// World → eye.
    pub view: [f32; 16],
    /// Eye → clip.
    pub projection: [f32; 16],
}

/// How [`deep_from_frame`] writes a DeepFrame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameOptions {
    /// Type of `R`, `G`, `B`, `A`: `Float` (default) or `Half`. `Z` is always `FLOAT`.
    pub color: SampleType,
    /// Also write `ZBack` (= `Z`); off by default, since absent `ZBack` means point samples.
    pub z_back: bool,
    /// Also write the exact window depth as `strata.depth` (default on; see the module docs).
    pub exact_depth: bool,
    /// Store `worldToCamera` and `worldToNDC` from these matrices.
    pub camera: Option<CameraMatrices>,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions {
            color: SampleType::Float,
            z_back: false,
            exact_depth: true,
            camera: None,
        }
    }
}

/// Converts a DeepFrame to a deep image (channels and attributes in the module docs).
///
/// # Errors
/// [`ExrError::InvalidImage`] if the frame is empty (0 pixels wide or high) or the colour type is
/// `Uint`.
pub fn deep_from_frame(
    frame: &DeepFrame,
    depth: DepthMapping,
    options: &FrameOptions,
) -> Result<DeepImage> {
    if options.color == SampleType::Uint {
        return Err(ExrError::InvalidImage(
            "colour channels must be HALF or FLOAT".into(),
        ));
    }
    let window = Box2i::from_origin(0, 0, frame.width(), frame.height())?;
    let colors = frame.colors();
    let colour = |f: fn(&Rgba8) -> f32| Column::F32(colors.iter().map(f).collect());
    let mut named: Vec<(Channel, Column)> = vec![
        (Channel::new("A", options.color), colour(|c| unorm(c.0[3]))),
        (
            Channel::new("B", options.color),
            colour(|c| premultiplied(c, 2)),
        ),
        (
            Channel::new("G", options.color),
            colour(|c| premultiplied(c, 1)),
        ),
        (
            Channel::new("R", options.color),
            colour(|c| premultiplied(c, 0)),
        ),
        (
            Channel::new("Z", SampleType::Float),
            Column::F32(
                frame
                    .depths()
                    .iter()
                    .map(|&d| depth.z_from_depth(d))
                    .collect(),
            ),
        ),
        (
            Channel::new(OBJECT_ID_CHANNEL, SampleType::Uint),
            Column::U32(frame.objects().iter().map(|o| o.0).collect()),
        ),
    ];
    if options.z_back {
        let z = named[4].1.clone();
        named.push((Channel::new("ZBack", SampleType::Float), z));
    }
    if options.exact_depth {
        named.push((
            Channel::new(WINDOW_DEPTH_CHANNEL, SampleType::Float),
            Column::F32(frame.depths().to_vec()),
        ));
    }
    named.sort_by(|a, b| a.0.name.cmp(&b.0.name));
    let (channels, columns) = named.into_iter().unzip();
    let mut image = DeepImage::new(window, channels, frame.offsets().to_vec(), columns)?;
    image.set_attribute(Attribute::double(NEAR_ATTRIBUTE, depth.near));
    image.set_attribute(Attribute::double(FAR_ATTRIBUTE, depth.far));
    if let Some(camera) = options.camera {
        image.set_attribute(Attribute::m44f("worldToCamera", camera.view));
        image.set_attribute(Attribute::m44f(
            "worldToNDC",
            mul_col_major(&camera.projection, &camera.view),
        ));
    }
    Ok(image)
}

fn unorm(v: u8) -> f32 {
    (f64::from(v) / 255.0) as f32
}

fn premultiplied(c: &Rgba8, i: usize) -> f32 {
    (f64::from(c.0[i]) / 255.0 * (f64::from(c.0[3]) / 255.0)) as f32
}

/// `a · b` for column-major 4×4 matrices.
fn mul_col_major(a: &[f32; 16], b: &[f32; 16]) -> [f32; 16] {
    let mut out = [0f32; 16];
    for col in 0..4 {
        for row in 0..4 {
            out[col * 4 + row] = (0..4).map(|k| a[k * 4 + row] * b[col * 4 + k]).sum();
        }
    }
    out
}

/// Channels [`frame_from_deep`] reads.
struct FrameChannels<'a> {
    r: &'a [f32],
    g: &'a [f32],
    b: &'a [f32],
    a: &'a [f32],
    z: &'a [f32],
    object: Option<&'a [u32]>,
    window_depth: Option<&'a [f32]>,
}

impl<'a> FrameChannels<'a> {
    fn find(image: &'a DeepImage) -> Result<Self> {
        let float = |name: &str| -> Result<&'a [f32]> {
            image
                .channel_index(name)
                .and_then(|c| image.columns[c].as_f32())
                .ok_or_else(|| ExrError::Frame(format!("the image has no float channel `{name}`")))
        };
        let object = [OBJECT_ID_CHANNEL, "id"].iter().find_map(|n| {
            image
                .channel_index(n)
                .and_then(|c| image.columns[c].as_u32())
        });
        let window_depth = image
            .channel_index(WINDOW_DEPTH_CHANNEL)
            .and_then(|c| image.columns[c].as_f32());
        Ok(FrameChannels {
            r: float("R")?,
            g: float("G")?,
            b: float("B")?,
            a: float("A")?,
            z: float("Z")?,
            object,
            window_depth,
        })
    }

    fn fragment(&self, s: usize, depth: Option<DepthMapping>) -> Fragment {
        let alpha = self.a[s];
        let a8 = to_u8(alpha);
        let straight = |c: f32| {
            if a8 == 0 {
                0
            } else {
                to_u8((f64::from(c) / f64::from(alpha)) as f32)
            }
        };
        Fragment {
            depth: self.depth(s, depth),
            color: Rgba8([
                straight(self.r[s]),
                straight(self.g[s]),
                straight(self.b[s]),
                a8,
            ]),
            object: ObjectId(self.object.map_or(0, |o| o[s])),
        }
    }

    fn depth(&self, s: usize, mapping: Option<DepthMapping>) -> f32 {
        let z = self.z[s];
        let exact = self
            .window_depth
            .map(|w| w[s])
            .filter(|d| (0.0..=1.0).contains(d))
            .map(clamp_depth);
        match (exact, mapping) {
            (Some(d), Some(m)) if m.z_from_depth(d).to_bits() == z.to_bits() => d,
            (Some(d), None) => d,
            (_, Some(m)) => m.depth_from_z(z),
            (None, None) => 0.0,
        }
    }
}

fn to_u8(v: f32) -> u8 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    (f64::from(v) * 255.0).round() as u8
}

/// Converts a deep image back to a DeepFrame (width and height of its data window).
///
/// Needs float channels `R`, `G`, `B`, `A` and `Z`; `objectid` (or `id`) is optional (0 when
/// absent). Depth comes from `strata.depth` when it agrees with `Z`, else from inverting `Z` with
/// `depth` or, when `None`, the mapping stored in the image's attributes.
///
/// # Errors
/// [`ExrError::Frame`] if a channel is missing, no depth mapping is known and there is no
/// `strata.depth` channel, or the samples do not form a valid DeepFrame.
pub fn frame_from_deep(image: &DeepImage, depth: Option<DepthMapping>) -> Result<DeepFrame> {
    let channels = FrameChannels::find(image)?;
    let mapping = depth.or_else(|| DepthMapping::from_attributes(image));
    if mapping.is_none() && channels.window_depth.is_none() {
        return Err(ExrError::Frame(
            "the clip planes are unknown (no strata.near/strata.far attributes); give them".into(),
        ));
    }
    let (w, h) = (image.width() as u32, image.height() as u32);
    let counts: Vec<u32> = image.offsets.windows(2).map(|o| o[1] - o[0]).collect();
    let offsets = &image.offsets;
    DeepFrame::build(w, h, &counts, |p, out| {
        for s in offsets[p] as usize..offsets[p + 1] as usize {
            out.push(channels.fragment(s, mapping));
        }
    })
    .map_err(|e| ExrError::Frame(e.to_string()))
}
