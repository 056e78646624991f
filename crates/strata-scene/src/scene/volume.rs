//! The scene file's `[volume]` table: a scalar volume, where it sits, its transfer function, and
//! the interactive well path drawn through it (the volume ray caster in `strata-volume` reads it).
//!
//! ```toml
//! [volume]
//! procedural = "head"            # or file = "ch2.nii.gz" (NIfTI-1, found like a mesh)
//! size = 64                      # voxels per side of the procedural volume
//! min = [-0.5, -0.5, -0.5]       # the box the volume fills (world units)
//! max = [0.5, 0.5, 0.5]
//! samples = 512                  # samples along the box's diagonal: step = diagonal / samples
//! unit_length = 0.1              # the thickness each point's alpha refers to
//! path = [[0, 0.8, 0], [0.1, 0, 0], [0.4, -0.4, 0.1]]   # the well path (optional)
//! path_radius = 0.02
//! path_color = [0.9, 0.25, 0.1]
//!
//! [[volume.points]]              # at least one; values strictly increasing
//! value = 0.2
//! color = [0.8, 0.5, 0.3]
//! alpha = 0.0
//!
//! [[volume.glass]]               # translucent boxes (optional, any number)
//! min = [0.3, -0.5, -0.6]
//! max = [0.32, 0.6, 0.6]
//! color = [0.4, 0.8, 1.0]
//! alpha = 0.35                   # opacity of each of its surfaces
//! moves = false                  # true: moved with the path by the fast client
//! ```
//!
//! Only the shape of the table is checked here (every key's type, range and line in errors); the
//! volume file is found on the search path but read by the ray caster.

use std::path::PathBuf;

use glam::Vec3;
use serde::Deserialize;

use super::file::Numbers;

/// Where the volume's voxels come from.
#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSource {
    /// A NIfTI-1 file (`.nii`, `.nii.gz`), resolved on the search path.
    File(PathBuf),
    /// A built-in procedural volume by name (`head`) with this many voxels per side.
    Procedural {
        /// The volume's name.
        name: String,
        /// Voxels per side.
        size: u32,
    },
}

/// One transfer-function point as written in the file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumePoint {
    /// Normalised scalar value in [0, 1].
    pub value: f32,
    /// Linear RGB in [0, 1].
    pub color: [f32; 3],
    /// Opacity of a `unit_length` slab, in [0, 1].
    pub alpha: f32,
}

/// The `[volume]` table, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeSpec {
    /// The voxels.
    pub source: VolumeSource,
    /// Minimum corner of the box the volume fills.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
    /// Samples along the box's diagonal.
    pub samples: u32,
    /// The thickness the points' alpha refers to.
    pub unit_length: f32,
    /// The transfer function's points, values strictly increasing.
    pub points: Vec<VolumePoint>,
    /// The interactive well path's points (empty: none).
    pub path: Vec<Vec3>,
    /// The path's tube radius.
    pub path_radius: f32,
    /// The path's colour.
    pub path_color: [f32; 3],
    /// Translucent boxes inside or around the volume.
    pub glass: Vec<VolumeGlass>,
}

/// One `[[volume.glass]]` entry: a translucent box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeGlass {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
    /// Linear RGB in [0, 1].
    pub color: [f32; 3],
    /// Opacity of each of its surfaces, in [0, 1].
    pub alpha: f32,
    /// Whether the fast client moves it with the path (otherwise the slow client draws it).
    pub moves: bool,
}

/// Built-in procedural volumes.
pub const PROCEDURAL_VOLUMES: &[&str] = &["head"];

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct VolumeFile {
    file: Option<String>,
    procedural: Option<String>,
    size: Option<i64>,
    min: Option<Numbers<3>>,
    max: Option<Numbers<3>>,
    samples: Option<i64>,
    unit_length: Option<f32>,
    #[serde(default)]
    points: Vec<PointFile>,
    #[serde(default)]
    path: Vec<Numbers<3>>,
    path_radius: Option<f32>,
    path_color: Option<Numbers<3>>,
    #[serde(default)]
    glass: Vec<GlassFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct GlassFile {
    min: Numbers<3>,
    max: Numbers<3>,
    color: Option<Numbers<3>>,
    alpha: f32,
    #[serde(default)]
    moves: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PointFile {
    value: f32,
    color: Numbers<3>,
    alpha: f32,
}

/// What a check needs from the scene resolver: errors at a key, and the search for files.
pub(super) trait Checker {
    /// An "invalid value" error at `key`.
    fn invalid_at(&self, key: &str, msg: String) -> super::SceneError;
    /// The file `name` on the search path, or the error listing where it was looked for.
    fn find_file(&self, key: &str, name: &str) -> Result<PathBuf, super::SceneError>;
}

pub(super) fn check(c: &impl Checker, f: VolumeFile) -> Result<VolumeSpec, super::SceneError> {
    let source = source(c, &f)?;
    let min = Vec3::from(f.min.map_or([-0.5; 3], |n| n.0));
    let max = Vec3::from(f.max.map_or([0.5; 3], |n| n.0));
    if !(min.is_finite() && max.is_finite() && min.cmplt(max).all()) {
        return Err(c.invalid_at(
            "volume.max",
            format!("the box {min} .. {max} must be finite with max above min on every axis"),
        ));
    }
    let samples = f.samples.unwrap_or(512);
    let samples = u32::try_from(samples)
        .ok()
        .filter(|s| (1..=1 << 16).contains(s))
        .ok_or_else(|| c.invalid_at("volume.samples", format!("{samples} is outside 1..=65536")))?;
    let unit_length = f.unit_length.unwrap_or(0.1);
    if !(unit_length.is_finite() && unit_length > 0.0) {
        return Err(c.invalid_at(
            "volume.unit_length",
            format!("{unit_length} must be a positive number"),
        ));
    }
    let points = points(c, &f.points)?;
    let path: Vec<Vec3> = f.path.iter().map(|p| Vec3::from(p.0)).collect();
    if path.len() == 1 || !path.iter().all(|p| p.is_finite()) {
        return Err(c.invalid_at(
            "volume.path",
            "a path needs at least 2 finite points".to_owned(),
        ));
    }
    let path_radius = f.path_radius.unwrap_or(0.02);
    if !(path_radius.is_finite() && path_radius > 0.0) {
        return Err(c.invalid_at(
            "volume.path_radius",
            format!("{path_radius} must be a positive number"),
        ));
    }
    let path_color = f.path_color.map_or([0.9, 0.25, 0.1], |n| n.0);
    if !path_color.iter().all(|v| (0.0..=1.0).contains(v)) {
        return Err(c.invalid_at(
            "volume.path_color",
            "each component must be in [0, 1]".to_owned(),
        ));
    }
    let glass = glass(c, &f.glass)?;
    Ok(VolumeSpec {
        source,
        min,
        max,
        samples,
        unit_length,
        points,
        path,
        path_radius,
        path_color,
        glass,
    })
}

fn glass(c: &impl Checker, boxes: &[GlassFile]) -> Result<Vec<VolumeGlass>, super::SceneError> {
    let unit = |v: f32| (0.0..=1.0).contains(&v);
    let mut out = Vec::with_capacity(boxes.len());
    for (i, g) in boxes.iter().enumerate() {
        let key = format!("volume.glass[{i}]");
        let (min, max) = (Vec3::from(g.min.0), Vec3::from(g.max.0));
        if !(min.is_finite() && max.is_finite() && min.cmplt(max).all()) {
            return Err(c.invalid_at(
                &key,
                format!("the box {min} .. {max} must be finite with max above min on every axis"),
            ));
        }
        let color = g.color.map_or([0.4, 0.8, 1.0], |n| n.0);
        if !color.iter().all(|&v| unit(v)) || !unit(g.alpha) {
            return Err(c.invalid_at(&key, "color and alpha must lie in [0, 1]".to_owned()));
        }
        out.push(VolumeGlass {
            min,
            max,
            color,
            alpha: g.alpha,
            moves: g.moves,
        });
    }
    Ok(out)
}

fn source(c: &impl Checker, f: &VolumeFile) -> Result<VolumeSource, super::SceneError> {
    match (&f.file, &f.procedural) {
        (Some(name), None) => Ok(VolumeSource::File(c.find_file("volume.file", name)?)),
        (None, Some(name)) => {
            if !PROCEDURAL_VOLUMES.contains(&name.as_str()) {
                return Err(c.invalid_at(
                    "volume.procedural",
                    format!("'{name}' is not a procedural volume (known: {PROCEDURAL_VOLUMES:?})"),
                ));
            }
            let size = f.size.unwrap_or(64);
            let size = u32::try_from(size)
                .ok()
                .filter(|s| (2..=512).contains(s))
                .ok_or_else(|| c.invalid_at("volume.size", format!("{size} is outside 2..=512")))?;
            Ok(VolumeSource::Procedural {
                name: name.clone(),
                size,
            })
        }
        _ => Err(c.invalid_at(
            "volume",
            "give exactly one of `file` (a NIfTI-1 volume) or `procedural` (\"head\")".to_owned(),
        )),
    }
}

fn points(c: &impl Checker, pts: &[PointFile]) -> Result<Vec<VolumePoint>, super::SceneError> {
    if pts.is_empty() {
        return Err(c.invalid_at(
            "volume.points",
            "the transfer function has no points; add at least one [[volume.points]] with value, color and alpha".to_owned(),
        ));
    }
    let unit = |v: f32| (0.0..=1.0).contains(&v);
    let mut out = Vec::with_capacity(pts.len());
    for (i, p) in pts.iter().enumerate() {
        let key = format!("volume.points[{i}]");
        if !unit(p.value) || !p.color.0.iter().all(|&v| unit(v)) || !unit(p.alpha) {
            return Err(c.invalid_at(
                &key,
                "value, color and alpha must all lie in [0, 1]".to_owned(),
            ));
        }
        if let Some(prev) = out.last().map(|q: &VolumePoint| q.value)
            && p.value <= prev
        {
            return Err(c.invalid_at(
                &key,
                format!(
                    "value {} does not follow the previous point's {prev}; values must increase",
                    p.value
                ),
            ));
        }
        out.push(VolumePoint {
            value: p.value,
            color: p.color.0,
            alpha: p.alpha,
        });
    }
    Ok(out)
}
