//! The reprojection transfer (seed 000 ch. 5, the "bilateral transformation"), without drift and
//! without the seed's merge artefacts.
//!
//! # What both ends hold
//!
//! For every node, a [`Held`] list: per pixel a run of [`Entry`]s sorted front to back. An entry
//! is a *surfel* — the object, the object-space position and the object-space normal of a
//! fragment — and the colour fragment that surfel shades to at the current frame. The node
//! renders **normal fragments** ([`strata_raster::FragmentOutput::PackedNormal`]: window depth, a
//! [`PackedNormal`] in the colour bytes, the object), and the wire carries them unchanged; the
//! eye-space position is the unprojection of the pixel centre at that depth (the seed stores eye
//! x, y, z per fragment — 24 bytes — strata derives x and y from the pixel, so a normal fragment
//! costs what a colour fragment does).
//!
//! When a normal fragment arrives, [`View::entry`] applies eq. 5.10 once — eye space to object
//! space with the inverse model-view of the frame it was rendered in — and every later frame
//! applies eq. 5.9 to that fixed object-space point with the current matrices ([`Held::reproject`]).
//! The seed re-derived eye positions from the previous frame's eye positions every frame, so
//! rounding accumulated and its difference lists grew over time (fig. 6.3); a surfel here is
//! transformed from the same object-space coordinates every frame and cannot drift.
//!
//! # One frame
//!
//! ```text
//! both ends:  held(t-1) ──reproject (eq. 5.9, P, viewport; shade; bucket; sort)──► projected(t)
//! node:       render normal fragments(t) ──► entries(t)   ─┐
//!             projected(t) ──match per pixel─────────────────┴─► removals + inserts (+ digest)
//! both ends:  projected(t) ── merge_pixel(removals, inserts) ──► held(t) ──► colour DeepFrame
//! ```
//!
//! **Matching** (node, per pixel): the rendered run, converted to entries exactly as the display
//! will convert them, is walked in order; a projected entry survives as the next rendered
//! fragment if it belongs to the same object and shades to a colour within `tolerance` 8-bit
//! steps of it (alpha equal). Projected entries skipped over are removed, rendered fragments
//! without a survivor are inserted. The node then merges survivors and inserts with the same
//! [`merge_pixel`] the display runs and checks the result against the rendered run — same length,
//! same object at every position, colours within `tolerance`; where it does not hold (a
//! reprojected depth out of order, say) the pixel is replaced whole. So each node's list on the
//! display shades, in order, to its own render within `tolerance`.
//!
//! **Removal by identity.** Both ends run the same code on the same inputs, so their projected
//! runs are bit-identical and a removal names an entry by its position in the run. The seed
//! removed "the nearest fragment by depth" within a threshold, which deleted the wrong fragments
//! when the threshold was large and kept stale ones when it was small (fig. 5.8, 5.9). To catch
//! the case where the two ends' arithmetic differs (different platforms, a bug), the node sends a
//! digest of its new state ([`Held::digest`]) with every frame and the display compares.

use glam::{Mat3, Mat4, Vec3, Vec4};
use rayon::prelude::*;
use strata_core::fragment::unorm8;
use strata_core::material::headlight_factor;
use strata_core::{DeepFrame, Fragment, ObjectId, PackedNormal, Rgba8, Shading};
use strata_scene::Scene;
use strata_wire::{MaskBuilder, PixelMask, Removals};

/// Rows per parallel band: fixed, so the digest and every result are the same at any thread count.
const BAND_ROWS: usize = 16;

/// How far (relative eye depth) a projected entry may lie from the rendered fragment it stands
/// for. Only an efficiency hint — the merged run is checked anyway — that keeps a fragment from
/// being matched to another surface of its object further back (which would remove everything
/// between them).
const DEPTH_SLACK: f32 = 0.01;

/// A fragment's surface point: object-space position and normal (zero: no normal).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Surfel {
    /// Object-space position.
    pub position: [f32; 3],
    /// Object-space normal (not normalised; zero when the fragment had none).
    pub normal: [f32; 3],
}

/// A held fragment: its surfel and what it shades to at the current frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Entry {
    /// Window depth, shaded colour and object at the current frame.
    pub fragment: Fragment,
    /// Where it is on its object.
    pub surfel: Surfel,
}

/// One object's matrices and material at one frame.
#[derive(Clone, Debug, PartialEq)]
struct ObjectView {
    model_view: Mat4,
    inverse_model_view: Mat4,
    /// Object → eye for normals: inverse-transpose of the model-view's 3×3.
    normal: Mat3,
    /// Eye → object for normals: the transpose of the model-view's 3×3.
    to_object_normal: Mat3,
    rgb: [f32; 3],
    alpha: u8,
    lit: bool,
    flat: Rgba8,
}

/// One frame's camera and object placements, as both ends compute them.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    width: u32,
    height: u32,
    projection: Mat4,
    inverse_projection: Mat4,
    /// Indexed by object id (scene ids are dense).
    objects: Vec<Option<ObjectView>>,
}

impl View {
    /// The view of `objects` of `scene` posed at animation frame `frame`, seen with `view` and
    /// `projection` at `width` × `height`. Objects not listed are unknown to it.
    pub fn new(
        scene: &Scene,
        objects: &[ObjectId],
        frame: u64,
        (width, height): (u32, u32),
        view: Mat4,
        projection: Mat4,
    ) -> View {
        let frame = u32::try_from(frame).unwrap_or(u32::MAX);
        let max = scene.objects.iter().map(|o| o.id.0).max().unwrap_or(0) as usize;
        let mut table = vec![None; max + 1];
        for o in scene.objects.iter().filter(|o| objects.contains(&o.id)) {
            let model_view = view * o.model_matrix(scene.animation.as_ref(), frame);
            let m3 = Mat3::from_mat4(model_view);
            let c = o.material.color;
            table[o.id.0 as usize] = Some(ObjectView {
                model_view,
                inverse_model_view: model_view.inverse(),
                normal: m3.inverse().transpose(),
                to_object_normal: m3.transpose(),
                rgb: [c[0], c[1], c[2]],
                alpha: unorm8(c[3]),
                lit: o.material.shading == Shading::Headlight,
                flat: Rgba8::from_unorm(c),
            });
        }
        View {
            width,
            height,
            projection,
            inverse_projection: projection.inverse(),
            objects: table,
        }
    }

    /// Frame size.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Distance from the eye plane of a fragment at window depth `depth` (for a perspective
    /// projection it does not depend on the pixel).
    #[inline]
    fn eye_depth(&self, depth: f32) -> f32 {
        // The z and w rows of P⁻¹ · (0, 0, z_ndc, 1).
        let (c, d) = (
            self.inverse_projection.z_axis,
            self.inverse_projection.w_axis,
        );
        let z = depth * 2.0 - 1.0;
        ((c.z * z + d.z) / (c.w * z + d.w)).abs()
    }

    /// True if `object` is placed and seen exactly as in `other`: reprojecting it from `other`
    /// to `self` is the identity, and is done as one (f32 arithmetic would move it by an ulp).
    fn unchanged(&self, other: &View, object: usize) -> bool {
        self.size() == other.size()
            && self.projection == other.projection
            && self.objects.get(object) == other.objects.get(object)
    }

    #[inline]
    fn object(&self, id: ObjectId) -> Option<&ObjectView> {
        self.objects.get(id.0 as usize).and_then(Option::as_ref)
    }

    /// The colour of `surfel` of object `o` at eye-space position `eye` (DESIGN §2 shading).
    #[inline]
    fn shade(o: &ObjectView, surfel: &Surfel, eye: Vec3) -> Rgba8 {
        if !o.lit {
            return o.flat;
        }
        let n = o.normal * Vec3::from(surfel.normal);
        let f = headlight_factor(n.to_array(), eye.to_array());
        Rgba8([
            unorm8(o.rgb[0] * f),
            unorm8(o.rgb[1] * f),
            unorm8(o.rgb[2] * f),
            o.alpha,
        ])
    }

    /// Eq. 5.9 and the viewport: the pixel `surfel` of `object` lands in and the fragment it
    /// shades to, or `None` if it leaves the view volume (or its object is unknown).
    #[inline]
    fn project(&self, object: ObjectId, surfel: &Surfel) -> Option<(u32, Fragment)> {
        let o = self.object(object)?;
        let eye = o.model_view.transform_point3(Vec3::from(surfel.position));
        let c = self.projection * eye.extend(1.0);
        if c.w.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let iw = 1.0 / c.w;
        let (xn, yn, zn) = (c.x * iw, c.y * iw, c.z * iw);
        let x = (xn * 0.5 + 0.5) * self.width as f32;
        let y = (0.5 - yn * 0.5) * self.height as f32;
        let z = zn * 0.5 + 0.5;
        // Written so that NaN fails every test.
        if !(x >= 0.0 && x < self.width as f32 && y >= 0.0 && y < self.height as f32) {
            return None;
        }
        if !((0.0..=1.0).contains(&z)) {
            return None;
        }
        let (px, py) = (
            (x as u32).min(self.width - 1),
            (y as u32).min(self.height - 1),
        );
        let depth = if z > 0.0 { z } else { 0.0 };
        Some((
            py * self.width + px,
            Fragment {
                depth,
                color: Self::shade(o, surfel, eye),
                object,
            },
        ))
    }

    /// Eq. 5.10 once: the entry of the normal fragment `f` rendered at `pixel` in this view —
    /// its surfel in object space and its colour now. `None` if its object is unknown.
    #[inline]
    pub fn entry(&self, pixel: u32, f: Fragment) -> Option<Entry> {
        let o = self.object(f.object)?;
        let (px, py) = (pixel % self.width, pixel / self.width);
        let ndc = Vec4::new(
            (px as f32 + 0.5) / self.width as f32 * 2.0 - 1.0,
            1.0 - (py as f32 + 0.5) / self.height as f32 * 2.0,
            f.depth * 2.0 - 1.0,
            1.0,
        );
        let e = self.inverse_projection * ndc;
        let eye = e.truncate() / e.w;
        let normal = match PackedNormal::from_bits(f.color.to_bits()).unpack() {
            Some(n) if o.lit => o.to_object_normal * Vec3::from(n),
            _ => Vec3::ZERO,
        };
        let surfel = Surfel {
            position: o.inverse_model_view.transform_point3(eye).to_array(),
            normal: normal.to_array(),
        };
        Some(Entry {
            fragment: Fragment {
                depth: f.depth,
                color: Self::shade(o, &surfel, eye),
                object: f.object,
            },
            surfel,
        })
    }
}

impl View {
    /// The colour fragments the normal fragments of `normals` (rendered at this view) shade to,
    /// runs sorted; fragments of unknown objects are left out.
    pub fn shade_frame(&self, normals: &DeepFrame) -> DeepFrame {
        let counts: Vec<u32> = (0..normals.offsets().len() - 1)
            .map(|p| {
                normals
                    .run(p)
                    .iter()
                    .filter(|f| self.object(f.object).is_some())
                    .count() as u32
            })
            .collect();
        DeepFrame::build(normals.width(), normals.height(), &counts, |p, out| {
            out.extend(
                normals
                    .run(p)
                    .iter()
                    .filter_map(|f| self.entry(p as u32, f).map(|e| e.fragment)),
            )
        })
        .unwrap_or_else(|_| DeepFrame::empty(normals.width(), normals.height()))
    }
}

/// For each node, the pixels whose order against another node's fragments the display cannot
/// trust: where fragments of two nodes lie within `2 · max(depth_error)` of each other (the bound
/// each node sent with its frame). Every node with fragments at such a pixel is asked for its
/// exact run there (nodes not taking part this frame are asked for nothing).
pub fn ambiguous(
    frames: &[&DeepFrame],
    depth_error: &[f32],
    taking_part: &[bool],
) -> Vec<PixelMask> {
    assert_eq!(frames.len(), taking_part.len());
    assert_eq!(frames.len(), depth_error.len());
    let Some(first) = frames.first() else {
        return Vec::new();
    };
    let pixels = first.offsets().len() - 1;
    let slack = 2.0
        * depth_error
            .iter()
            .zip(taking_part)
            .filter(|&(_, &t)| t)
            .map(|(&e, _)| e)
            .fold(0f32, f32::max);
    let flags: Vec<bool> = (0..pixels)
        .into_par_iter()
        .with_min_len(4096)
        .map(|p| {
            let mut depths: Vec<(f32, usize)> = Vec::new();
            for (i, f) in frames.iter().enumerate() {
                depths.extend(f.run(p).iter().map(|x| (x.depth, i)));
            }
            if depths.len() < 2 || slack <= 0.0 {
                return false;
            }
            depths.sort_by(|a, b| a.0.total_cmp(&b.0));
            depths
                .windows(2)
                .any(|w| w[0].1 != w[1].1 && w[1].0 - w[0].0 <= slack)
        })
        .collect();
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut b = MaskBuilder::new(pixels as u32);
            if taking_part[i] {
                for (p, &flag) in flags.iter().enumerate() {
                    if flag && !f.run(p).is_empty() {
                        b.push(p as u32);
                    }
                }
            }
            b.finish()
        })
        .collect()
}

/// Per pixel, a sorted run of entries: what one node's fragments are on both ends.
#[derive(Clone, Debug, PartialEq)]
pub struct Held {
    width: u32,
    height: u32,
    /// `offsets[p]..offsets[p + 1]` indexes `entries` for pixel `p`.
    offsets: Vec<u32>,
    entries: Vec<Entry>,
    /// The view the entries are shaded and bucketed for (none when empty).
    view: Option<View>,
}

impl Held {
    /// Nothing held.
    pub fn empty(width: u32, height: u32) -> Self {
        Held {
            width,
            height,
            offsets: vec![0; width as usize * height as usize + 1],
            entries: Vec::new(),
            view: None,
        }
    }

    /// Fragments held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True if nothing is held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Pixel `p`'s run.
    pub fn run(&self, p: usize) -> &[Entry] {
        &self.entries[self.offsets[p] as usize..self.offsets[p + 1] as usize]
    }

    /// Every held surfel moved to `view` (eq. 5.9), shaded, bucketed by the pixel it lands in and
    /// sorted front to back (stably: equal keys keep the order of this list). Objects whose
    /// matrices did not change keep their pixel and fragment bit for bit.
    pub fn reproject(&self, view: &View) -> Held {
        let mut out = Held::empty(0, 0);
        self.reproject_into(view, &mut out, &mut Scratch::default());
        out
    }

    /// [`Held::reproject`] into `out`, reusing its buffers and `scratch`'s (no allocation once
    /// they have grown to the scene's needs).
    pub fn reproject_into(&self, view: &View, out: &mut Held, scratch: &mut Scratch) {
        let (width, height) = view.size();
        let pixels = width as usize * height as usize;
        let unchanged: Vec<bool> = match &self.view {
            Some(old) => (0..view.objects.len())
                .map(|o| view.unchanged(old, o))
                .collect(),
            None => Vec::new(),
        };
        let moved = &mut scratch.moved;
        moved.clear();
        moved.resize(self.entries.len(), (u32::MAX, Fragment::default()));
        {
            let w = self.width as usize;
            let offsets = &self.offsets;
            let mut bands: Vec<(usize, &mut [(u32, Fragment)])> = Vec::new();
            let mut rest: &mut [(u32, Fragment)] = moved;
            let mut row = 0;
            while row < self.height as usize {
                let end = (row + BAND_ROWS).min(self.height as usize);
                let n = (offsets[end * w] - offsets[row * w]) as usize;
                let (band, tail) = std::mem::take(&mut rest).split_at_mut(n);
                bands.push((row, band));
                rest = tail;
                row = end;
            }
            bands.into_par_iter().for_each(|(row, band)| {
                let base = offsets[row * w] as usize;
                let end = (row + BAND_ROWS).min(self.height as usize);
                for p in row * w..end * w {
                    for i in offsets[p] as usize..offsets[p + 1] as usize {
                        let e = &self.entries[i];
                        let o = e.fragment.object.0 as usize;
                        band[i - base] = if unchanged.get(o) == Some(&true) {
                            (p as u32, e.fragment)
                        } else {
                            view.project(e.fragment.object, &e.surfel)
                                .unwrap_or((u32::MAX, Fragment::default()))
                        };
                    }
                }
            });
        }
        let offsets = &mut out.offsets;
        offsets.clear();
        offsets.resize(pixels + 1, 0);
        for &(p, _) in moved.iter() {
            if p != u32::MAX {
                offsets[p as usize + 1] += 1;
            }
        }
        for p in 0..pixels {
            offsets[p + 1] += offsets[p];
        }
        let total = offsets[pixels] as usize;
        out.entries.clear();
        out.entries.resize(total, Entry::default());
        let cursor = &mut scratch.cursor;
        cursor.clear();
        cursor.extend_from_slice(&offsets[..pixels]);
        for (e, &(p, f)) in self.entries.iter().zip(moved.iter()) {
            if p != u32::MAX {
                let c = &mut cursor[p as usize];
                out.entries[*c as usize] = Entry {
                    fragment: f,
                    surfel: e.surfel,
                };
                *c += 1;
            }
        }
        out.width = width;
        out.height = height;
        out.view = Some(view.clone());
        out.sort_runs();
    }

    /// Empties this list for a `width` × `height` frame, keeping its buffers.
    fn clear_to(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        self.offsets.clear();
        self.offsets.resize(width as usize * height as usize + 1, 0);
        self.entries.clear();
        self.view = None;
    }

    /// Sorts every run front to back, stably, in parallel bands.
    fn sort_runs(&mut self) {
        let width = self.width as usize;
        let offsets = &self.offsets;
        let mut bands: Vec<(usize, &mut [Entry])> = Vec::new();
        let mut rest: &mut [Entry] = &mut self.entries;
        let mut row = 0;
        while row < self.height as usize {
            let end = (row + BAND_ROWS).min(self.height as usize);
            let n = (offsets[end * width] - offsets[row * width]) as usize;
            let (band, tail) = std::mem::take(&mut rest).split_at_mut(n);
            bands.push((row, band));
            rest = tail;
            row = end;
        }
        bands.into_par_iter().for_each(|(row, band)| {
            let base = offsets[row * width] as usize;
            let end = (row + BAND_ROWS).min(self.height as usize);
            for p in row * width..end * width {
                let run = &mut band[offsets[p] as usize - base..offsets[p + 1] as usize - base];
                sort_entries(run);
            }
        });
    }

    /// The colour DeepFrame the display resolves.
    pub fn to_frame(&self) -> DeepFrame {
        let depth = self.entries.iter().map(|e| e.fragment.depth).collect();
        let color = self.entries.iter().map(|e| e.fragment.color).collect();
        let object = self.entries.iter().map(|e| e.fragment.object).collect();
        // Runs are sorted by the fragment order, so this cannot fail.
        DeepFrame::from_parts(
            self.width,
            self.height,
            self.offsets.clone(),
            depth,
            color,
            object,
        )
        .unwrap_or_else(|_| DeepFrame::empty(self.width, self.height))
    }

    /// A 64-bit digest of what is held — run lengths, fragments and surfel positions, in order —
    /// computed over fixed bands, so it does not depend on the thread count.
    pub fn digest(&self) -> u64 {
        let width = self.width as usize;
        let bands = (self.height as usize).div_ceil(BAND_ROWS);
        let parts: Vec<u64> = (0..bands)
            .into_par_iter()
            .map(|b| {
                let mut h = Digest::new(b as u64);
                let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(self.height as usize);
                for p in rows.start * width..rows.end * width {
                    let run = self.run(p);
                    h.word(run.len() as u64);
                    for e in run {
                        // The fragment and the position say everything the next frames derive
                        // from an entry (its normal only feeds the colour, which is in here).
                        let (f, q) = (&e.fragment, &e.surfel.position);
                        h.word(u64::from(f.depth.to_bits()) << 32 | u64::from(f.color.to_bits()));
                        h.word(u64::from(f.object.0) << 32 | u64::from(q[0].to_bits()));
                        h.word(u64::from(q[1].to_bits()) << 32 | u64::from(q[2].to_bits()));
                    }
                }
                h.finish()
            })
            .collect();
        let mut h = Digest::new(u64::from(self.width) << 32 | u64::from(self.height));
        for p in parts {
            h.word(p);
        }
        h.finish()
    }
}

/// Buffers [`Held::reproject_into`] reuses from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    moved: Vec<(u32, Fragment)>,
    cursor: Vec<u32>,
}

/// A small multiply-rotate hash (not cryptographic: it detects divergence, not tampering).
struct Digest(u64);

impl Digest {
    fn new(seed: u64) -> Self {
        Digest(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    #[inline]
    fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w)
            .wrapping_mul(0xBF58_476D_1CE4_E5B9)
            .rotate_left(29);
    }
    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// Stable insertion sort of a run by the fragments' order (runs are a pixel's depth complexity).
fn sort_entries(run: &mut [Entry]) {
    for i in 1..run.len() {
        let item = run[i];
        let key = item.fragment.order_key();
        let mut j = i;
        while j > 0 && run[j - 1].fragment.order_key() > key {
            run[j] = run[j - 1];
            j -= 1;
        }
        run[j] = item;
    }
}

/// One pixel's new run: `projected` without the positions in `removed` (strictly increasing),
/// merged with the sorted `inserts`; on equal keys the projected entry comes first. Both ends
/// call exactly this, so their runs agree bit for bit.
pub fn merge_pixel(projected: &[Entry], removed: &[u32], inserts: &[Entry], out: &mut Vec<Entry>) {
    let mut r = removed.iter().peekable();
    let mut ins = inserts.iter().peekable();
    for (i, e) in projected.iter().enumerate() {
        if r.peek() == Some(&&(i as u32)) {
            r.next();
            continue;
        }
        while let Some(n) = ins.peek() {
            if n.fragment.order_key() < e.fragment.order_key() {
                out.push(**n);
                ins.next();
            } else {
                break;
            }
        }
        out.push(*e);
    }
    out.extend(ins.copied());
}

/// True if `a` stands for `b`: same object, same alpha, RGB within `tolerance` steps.
#[inline]
fn close(a: &Fragment, b: &Fragment, tolerance: u8) -> bool {
    let (x, y) = (a.color.0, b.color.0);
    a.object == b.object && x[3] == y[3] && (0..3).all(|c| x[c].abs_diff(y[c]) <= tolerance)
}

/// What a node sends for one frame.
#[derive(Clone, Debug)]
pub struct ReprojDelta {
    /// Pixels with removals or inserts.
    pub touched: PixelMask,
    /// Per touched pixel, the projected positions removed; with the digest of the new state.
    pub removals: Removals,
    /// The inserted normal fragments (none outside `touched`).
    pub inserts: DeepFrame,
    /// Fragments the display will hold after applying it.
    pub held: u64,
}

/// The node's side: its copy of what the display holds, and the matching.
#[derive(Clone, Debug)]
pub struct ReprojEncoder {
    tolerance: u8,
    held: Option<Held>,
    /// Buffers reused from frame to frame.
    projected: Held,
    scratch: Scratch,
    bands: Vec<BandOut>,
}

/// One band's share of a node frame.
#[derive(Clone, Debug, Default)]
struct BandOut {
    entries: Vec<Entry>,
    counts: Vec<u32>,
    touched: Vec<u32>,
    /// Per touched pixel, how many of `removed` are its.
    removed_counts: Vec<u32>,
    removed: Vec<u32>,
    /// Inserted normal fragments, per touched pixel in order.
    insert_counts: Vec<u32>,
    inserts: Vec<Fragment>,
    /// Largest |kept depth − rendered depth|.
    depth_error: f32,
}

impl ReprojEncoder {
    /// A node-side state that lets colours differ by at most `tolerance` 8-bit steps.
    pub fn new(tolerance: u8) -> Self {
        ReprojEncoder {
            tolerance,
            held: None,
            projected: Held::empty(0, 0),
            scratch: Scratch::default(),
            bands: Vec::new(),
        }
    }

    /// Forgets the display's state (a reset request): the next frame is sent whole.
    pub fn reset(&mut self) {
        self.held = None;
    }

    /// The delta that takes the display from the previous frame's state to `rendered` (normal
    /// fragments rendered at `view`), and the new state kept for the next frame.
    pub fn encode(&mut self, view: &View, rendered: &DeepFrame) -> ReprojDelta {
        let (width, height) = view.size();
        let old = self.held.take();
        match &old {
            Some(h) => h.reproject_into(view, &mut self.projected, &mut self.scratch),
            None => self.projected.clear_to(width, height),
        }
        let projected = &self.projected;
        let w = width as usize;
        let bands = (height as usize).div_ceil(BAND_ROWS);
        let tolerance = self.tolerance;
        self.bands.resize_with(bands, BandOut::default);
        self.bands.par_iter_mut().enumerate().for_each(|(b, out)| {
            out.entries.clear();
            out.counts.clear();
            out.touched.clear();
            out.removed_counts.clear();
            out.removed.clear();
            out.insert_counts.clear();
            out.inserts.clear();
            out.depth_error = 0.0;
            let mut truth: Vec<(Entry, Fragment)> = Vec::new();
            let mut removed: Vec<u32> = Vec::new();
            let mut inserts: Vec<Entry> = Vec::new();
            let mut inserted_wire: Vec<Fragment> = Vec::new();
            let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height as usize);
            for p in rows.start * w..rows.end * w {
                truth.clear();
                for f in rendered.run(p).iter() {
                    if let Some(e) = view.entry(p as u32, f) {
                        truth.push((e, f));
                    }
                }
                sort_truth(&mut truth);
                let held = projected.run(p);
                removed.clear();
                inserts.clear();
                inserted_wire.clear();
                let mut j = 0;
                for (n, f) in &truth {
                    let z = view.eye_depth(n.fragment.depth);
                    match held[j..].iter().position(|h| {
                        close(&h.fragment, &n.fragment, tolerance)
                            && (view.eye_depth(h.fragment.depth) - z).abs() <= DEPTH_SLACK * z
                    }) {
                        Some(k) => {
                            removed.extend(j as u32..(j + k) as u32);
                            j += k + 1;
                        }
                        None => {
                            inserts.push(*n);
                            inserted_wire.push(*f);
                        }
                    }
                }
                removed.extend(j as u32..held.len() as u32);
                let start = out.entries.len();
                merge_pixel(held, &removed, &inserts, &mut out.entries);
                let merged = &out.entries[start..];
                let ok = merged.len() == truth.len()
                    && merged
                        .iter()
                        .zip(&truth)
                        .all(|(m, (n, _))| close(&m.fragment, &n.fragment, tolerance));
                if ok {
                    for (m, (n, _)) in merged.iter().zip(&truth) {
                        let e = (m.fragment.depth - n.fragment.depth).abs();
                        out.depth_error = out.depth_error.max(e);
                    }
                } else {
                    out.entries.truncate(start);
                    removed.clear();
                    removed.extend(0..held.len() as u32);
                    inserts.clear();
                    inserted_wire.clear();
                    for (n, f) in &truth {
                        inserts.push(*n);
                        inserted_wire.push(*f);
                    }
                    merge_pixel(held, &removed, &inserts, &mut out.entries);
                }
                out.counts.push((out.entries.len() - start) as u32);
                if !removed.is_empty() || !inserts.is_empty() {
                    out.touched.push(p as u32);
                    out.removed_counts.push(removed.len() as u32);
                    out.removed.extend_from_slice(&removed);
                    out.insert_counts.push(inserted_wire.len() as u32);
                    out.inserts.extend_from_slice(&inserted_wire);
                }
            }
        });

        // Assemble the new state (in the old state's buffers), the mask, the removals and the
        // inserts, band by band.
        let pixels = w * height as usize;
        let (mut offsets, mut entries) = old.map(|h| (h.offsets, h.entries)).unwrap_or_default();
        offsets.clear();
        offsets.push(0u32);
        entries.clear();
        let mut mask = MaskBuilder::new(pixels as u32);
        let mut removals = Removals::new(0);
        let mut insert_counts = vec![0u32; pixels];
        let mut insert_list: Vec<Fragment> = Vec::new();
        let mut depth_error = 0f32;
        for o in &self.bands {
            depth_error = depth_error.max(o.depth_error);
            for &c in &o.counts {
                let last = *offsets.last().unwrap_or(&0);
                offsets.push(last + c);
            }
            entries.extend_from_slice(&o.entries);
            let mut at = 0;
            for (k, &p) in o.touched.iter().enumerate() {
                mask.push(p);
                let n = o.removed_counts[k] as usize;
                removals.push_pixel(o.removed[at..at + n].iter().copied());
                at += n;
                insert_counts[p as usize] = o.insert_counts[k];
            }
            insert_list.extend_from_slice(&o.inserts);
        }
        let held = Held {
            width,
            height,
            offsets,
            entries,
            view: Some(view.clone()),
        };
        removals.set_checksum(held.digest());
        removals.set_depth_error(depth_error);
        let mut starts = Vec::with_capacity(pixels + 1);
        let mut acc = 0u32;
        for &c in &insert_counts {
            starts.push(acc);
            acc += c;
        }
        starts.push(acc);
        // The inserts were rendered fragments: every run is at most a pixel's depth complexity,
        // and the total fits the rendered frame, so building cannot fail.
        let inserts = DeepFrame::build(width, height, &insert_counts, |p, out| {
            out.extend_from_slice(&insert_list[starts[p] as usize..starts[p + 1] as usize]);
        })
        .unwrap_or_else(|_| DeepFrame::empty(width, height));
        let count = held.len() as u64;
        self.held = Some(held);
        ReprojDelta {
            touched: mask.finish(),
            removals,
            inserts,
            held: count,
        }
    }
}

/// Sorts (entry, wire fragment) pairs by the entry's order, stably.
fn sort_truth(run: &mut [(Entry, Fragment)]) {
    for i in 1..run.len() {
        let item = run[i];
        let key = item.0.fragment.order_key();
        let mut j = i;
        while j > 0 && run[j - 1].0.fragment.order_key() > key {
            run[j] = run[j - 1];
            j -= 1;
        }
        run[j] = item;
    }
}

/// Why a display could not apply a reprojection frame.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ApplyError {
    /// The frame does not fit the held state (a removal beyond a run, a size change mid-stream).
    #[error("the reprojection frame does not fit the held fragments: {0}")]
    Mismatch(String),
    /// The states differ after applying: the two ends computed differently.
    #[error(
        "the reprojected state diverged from the node's (digest {ours:016x}, node {theirs:016x})"
    )]
    Diverged {
        /// The display's digest.
        ours: u64,
        /// The node's.
        theirs: u64,
    },
}

/// One band's new runs: the entries and each pixel's count.
type BandRuns = (Vec<Entry>, Vec<u32>);

/// The display's side: one node's held fragments.
#[derive(Clone, Debug)]
pub struct ReprojCopy {
    held: Held,
    /// Buffers reused from frame to frame: the reprojected list, the next state, bands.
    projected: Held,
    spare: Held,
    scratch: Scratch,
    slot: Vec<u32>,
    bands: Vec<BandRuns>,
}

impl ReprojCopy {
    /// Nothing held (the first frame of a connection is sent whole).
    pub fn empty(width: u32, height: u32) -> Self {
        ReprojCopy {
            held: Held::empty(width, height),
            projected: Held::empty(0, 0),
            spare: Held::empty(0, 0),
            scratch: Scratch::default(),
            slot: Vec::new(),
            bands: Vec::new(),
        }
    }

    /// What is held.
    pub fn held(&self) -> &Held {
        &self.held
    }

    /// Moves the held fragments to `view`, applies the node's removals and inserts, and checks
    /// the digest. On error the copy is left as it was.
    pub fn apply(
        &mut self,
        view: &View,
        touched: &PixelMask,
        removals: &Removals,
        inserts: &DeepFrame,
    ) -> Result<(), ApplyError> {
        let (width, height) = view.size();
        if (inserts.width(), inserts.height()) != (width, height)
            || touched.frame_pixels() as usize != width as usize * height as usize
            || removals.pixel_count() != touched.len() as usize
        {
            return Err(ApplyError::Mismatch(format!(
                "a {}x{} frame with {} touched pixels and {} removal entries for a {width}x{height} view",
                inserts.width(),
                inserts.height(),
                touched.len(),
                removals.pixel_count()
            )));
        }
        self.held
            .reproject_into(view, &mut self.projected, &mut self.scratch);
        let projected = &self.projected;
        let pixels = width as usize * height as usize;
        // Which removal entry each touched pixel owns.
        let slot = &mut self.slot;
        slot.clear();
        slot.resize(pixels, u32::MAX);
        for (k, p) in touched.iter().enumerate() {
            slot[p as usize] = k as u32;
        }
        let slot = &*slot;
        let w = width as usize;
        let bands = (height as usize).div_ceil(BAND_ROWS);
        self.bands.resize_with(bands, BandRuns::default);
        let results: Vec<Result<(), ApplyError>> = self
            .bands
            .par_iter_mut()
            .enumerate()
            .map(|(b, (entries, counts))| {
                entries.clear();
                counts.clear();
                let mut ins: Vec<Entry> = Vec::new();
                let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height as usize);
                let first = rows.start * w;
                for (p, &k) in (first..).zip(&slot[first..rows.end * w]) {
                    let start = entries.len();
                    let held = projected.run(p);
                    match k {
                        u32::MAX => entries.extend_from_slice(held),
                        k => {
                            let removed = removals.pixel(k as usize);
                            if let Some(&last) = removed.last()
                                && last as usize >= held.len()
                            {
                                return Err(ApplyError::Mismatch(format!(
                                    "pixel {p} holds {} fragments, the node removes position {last}",
                                    held.len()
                                )));
                            }
                            ins.clear();
                            for f in inserts.run(p).iter() {
                                let e = view.entry(p as u32, f).ok_or_else(|| {
                                    ApplyError::Mismatch(format!(
                                        "pixel {p}: object {} is not in the scene",
                                        f.object.0
                                    ))
                                })?;
                                ins.push(e);
                            }
                            sort_entries(&mut ins);
                            merge_pixel(held, removed, &ins, entries);
                        }
                    }
                    counts.push((entries.len() - start) as u32);
                }
                Ok(())
            })
            .collect();
        results.into_iter().collect::<Result<(), ApplyError>>()?;
        let held = &mut self.spare;
        held.width = width;
        held.height = height;
        held.view = Some(view.clone());
        held.offsets.clear();
        held.offsets.push(0u32);
        held.entries.clear();
        for (e, counts) in &self.bands {
            for &c in counts {
                let last = *held.offsets.last().unwrap_or(&0);
                held.offsets.push(last + c);
            }
            held.entries.extend_from_slice(e);
        }
        let ours = held.digest();
        if ours != removals.checksum() {
            return Err(ApplyError::Diverged {
                ours,
                theirs: removals.checksum(),
            });
        }
        std::mem::swap(&mut self.held, &mut self.spare);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::Rgb8Image;
    use strata_raster::{FragmentOutput, FrameInput, Rasterizer};
    use strata_scene::{Animation, SearchPath, open_scene};
    use strata_stores::{MethodOptions, create};

    const W: u32 = 128;
    const H: u32 = 96;

    /// `scene` turning `deg` degrees per frame about y.
    fn scene(name: &str, deg: f32) -> Scene {
        let mut s = open_scene(name, &SearchPath::new([])).expect("built-in scene");
        s.animation = Some(Animation {
            frames: 72,
            rotate_deg_per_frame: glam::Vec3::new(0.0, deg, 0.0),
        });
        s
    }

    /// Renders `objects` of `scene` at `frame` as normal or shaded fragments, `W` × `H`.
    fn render(
        scene: &Scene,
        objects: &[ObjectId],
        frame: u64,
        output: FragmentOutput,
    ) -> DeepFrame {
        let mut input = FrameInput::from_scene(scene, frame as u32);
        input.objects.retain(|o| objects.contains(&o.id));
        input.output = output;
        input.width = W;
        input.height = H;
        input.projection = scene.camera.projection(W, H);
        let mut store = create("abuffer", &MethodOptions::default()).expect("the A-buffer");
        store.clear(W, H).expect("clear");
        store
            .capture(&mut Rasterizer::default(), &input, &mut Default::default())
            .expect("capture");
        store.deep_frame().expect("exports").expect("a DeepFrame")
    }

    fn view(scene: &Scene, objects: &[ObjectId], frame: u64) -> View {
        View::new(
            scene,
            objects,
            frame,
            (W, H),
            scene.camera.view(),
            scene.camera.projection(W, H),
        )
    }

    fn max_channel_diff(a: &Rgb8Image, b: &Rgb8Image) -> u8 {
        a.as_bytes()
            .iter()
            .zip(b.as_bytes())
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0)
    }

    /// Runs node and display side by side for `frames` frames; returns the fragments inserted per
    /// frame and checks every displayed image against the exact render.
    fn run(scene: &Scene, frames: u64, tolerance: u8) -> Vec<usize> {
        let ids: Vec<ObjectId> = scene.objects.iter().map(|o| o.id).collect();
        let mut enc = ReprojEncoder::new(tolerance);
        let mut copy = ReprojCopy::empty(W, H);
        let mut sent = Vec::new();
        for t in 0..frames {
            let v = view(scene, &ids, t);
            let rendered = render(scene, &ids, t, FragmentOutput::PackedNormal);
            let d = enc.encode(&v, &rendered);
            copy.apply(&v, &d.touched, &d.removals, &d.inserts)
                .expect("the display follows the node");
            assert_eq!(copy.held().len() as u64, d.held);
            assert_eq!(copy.held().len(), rendered.fragment_count());
            let image = copy.held().to_frame().resolve(scene.background);
            let exact = render(scene, &ids, t, FragmentOutput::Shaded).resolve(scene.background);
            let diff = max_channel_diff(&image, &exact);
            assert!(
                diff <= tolerance + 1,
                "frame {t}: a channel differs by {diff} (tolerance {tolerance})"
            );
            sent.push(d.inserts.fragment_count());
        }
        sent
    }

    #[test]
    fn static_view_sends_nothing_after_the_first_frame() {
        let sent = run(&scene("spheres", 0.0), 4, 1);
        assert!(sent[0] > 1000, "{sent:?}");
        assert!(sent[1..].iter().all(|&n| n == 0), "{sent:?}");
    }

    #[test]
    fn turning_scene_stays_within_the_tolerance_and_sends_less_than_everything() {
        let sent = run(&scene("spheres", 2.0), 6, 2);
        assert!(sent[1..].iter().all(|&n| n < sent[0]), "{sent:?}");
    }

    #[test]
    fn zero_tolerance_is_exact_colour_for_colour() {
        run(&scene("mixed", 5.0), 4, 0);
    }

    #[test]
    fn a_removal_beyond_a_run_or_a_wrong_digest_is_an_error_and_keeps_the_copy() {
        let s = scene("spheres", 0.0);
        let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
        let v = view(&s, &ids, 0);
        let mut enc = ReprojEncoder::new(1);
        let d = enc.encode(&v, &render(&s, &ids, 0, FragmentOutput::PackedNormal));
        let mut copy = ReprojCopy::empty(W, H);
        let mut bad = d.removals.clone();
        bad.set_checksum(d.removals.checksum() ^ 1);
        assert!(matches!(
            copy.apply(&v, &d.touched, &bad, &d.inserts),
            Err(ApplyError::Diverged { .. })
        ));
        assert!(copy.held().is_empty());
        copy.apply(&v, &d.touched, &d.removals, &d.inserts).unwrap();
        // A removal at a position the pixel does not hold.
        let p = d.touched.iter().next().unwrap();
        let touched = PixelMask::from_fn(W * H, |q| q == p);
        let mut r = Removals::new(0);
        r.push_pixel([1000]);
        let before = copy.held().clone();
        assert!(matches!(
            copy.apply(&v, &touched, &r, &DeepFrame::empty(W, H)),
            Err(ApplyError::Mismatch(_))
        ));
        assert_eq!(copy.held(), &before);
    }

    #[test]
    fn digest_and_reprojection_do_not_depend_on_the_thread_count() {
        let s = scene("mixed", 5.0);
        let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
        let go = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let mut enc = ReprojEncoder::new(1);
                    let mut digests = Vec::new();
                    for t in 0..3 {
                        let d = enc.encode(
                            &view(&s, &ids, t),
                            &render(&s, &ids, t, FragmentOutput::PackedNormal),
                        );
                        digests.push((d.removals.checksum(), d.inserts.fragment_count()));
                    }
                    digests
                })
        };
        assert_eq!(go(1), go(3));
    }

    #[test]
    fn merge_pixel_keeps_projected_first_on_ties() {
        let e = |d: f32, o: u32| Entry {
            fragment: Fragment {
                depth: d,
                color: Rgba8([1, 2, 3, 4]),
                object: ObjectId(o),
            },
            surfel: Surfel::default(),
        };
        let mut tie = e(0.5, 1);
        tie.surfel.position[0] = 9.0;
        let mut out = Vec::new();
        merge_pixel(
            &[e(0.1, 0), e(0.5, 1), e(0.9, 2)],
            &[0],
            &[tie, e(0.95, 3)],
            &mut out,
        );
        assert_eq!(out, [e(0.5, 1), tie, e(0.9, 2), e(0.95, 3)]);
    }
}
