//! TFSS, the transparent fragment storage system of Lin 2007 (ch. 3): an SSA table, a T-buffer of
//! `L_num`-fragment sections and an NSA table, with optional leading-zeros elimination (§3.3).
//!
//! # Layout
//!
//! ```text
//! ssa:     [u32; w*h]          start-section address of each pixel, NULL (u32::MAX) if none
//!                              (the SSA table, §3.2.2.1)
//! t-buffer: sections of L_num fragment slots (§3.2.2.2), one of two formats:
//!   plain   [u32; 3·L_num] per section = 12·L_num bytes:
//!             depth bits × L_num | rgba × L_num | object id × L_num
//!             an empty slot has depth bits EMPTY (u32::MAX, a NaN no fragment carries)
//!   packed  (leading_zeros) a bit array, section_bits = 64·L_num + area bits per section:
//!             depth (32) × L_num | object id (32) × L_num | colour area of `area` bits holding
//!             one record per fragment, back to back: alpha (8) | R,G,B (3·len)
//! length:  (packed only) the Length table (§3.3.2), 4 bits per slot, L_num slots per section:
//!             0 empty, len + 1 stored (len 0..=8), 15 sealed — see `lz::LengthCode`
//! nsa:     [u32; sections]     next-section address of each section, NULL at the end of a chain
//!                              (the NSA table, §3.2.2.3)
//! next_free: AtomicU32         the section allocation counter
//! ```
//!
//! strata's fragment keeps its object id, so a plain section is `L_num × 12` bytes where the thesis's
//! is `L_num × 8` (depth and RGBA); `tfss::model` evaluates the thesis's sizes.
//!
//! # Passes
//!
//! - **clear**: every SSA entry to NULL, the counter to 0. Sections are initialised when they are
//!   allocated, so nothing proportional to the pool is touched.
//! - **capture** — the store flow of §3.2.3.1 (Figure 3-8), per fragment: read the pixel's SSA
//!   entry; no start section → allocate one and record it in the SSA table. Otherwise follow the
//!   NSA entries to the section with room; if it is full, allocate a new section and record it in
//!   its NSA entry. A section gets a successor only once it is full, so the first section with
//!   room is always the last of the chain: the walk reads NSA entries only (`⌊k / L_num⌋` of them
//!   for a pixel's `k`-th fragment, as `model::tfss_store_accesses` counts) and tests the last
//!   section alone, where the thesis's flowchart tests each section on the way. Every fragment
//!   walks its pixel's chain from the start, as the thesis's flow does — no per-pixel tail pointer,
//!   which would cost a second `w*h` table the thesis does not have — and a pixel's fragments sit
//!   in its chain in arrival order.
//!   As in the linked list, the rasterizer hands each strip of rows to one thread, so SSA entries
//!   are plain stores into the strip's `chunks_mut` slice; sections are reserved from the shared
//!   counter in blocks of 64 to 1,024 (`crate::alloc::block_size`), and a section — its slots, NSA entry
//!   and Length entries — is written only by the strip thread that reserved it. T-buffer and NSA
//!   words are atomics written with `Relaxed` stores, which keeps them shareable without `unsafe`
//!   (a packed field is or-ed into its word with a load and a store: `bits` says why that is
//!   enough).
//! - **resolve** — the read flow of §3.2.3.2 (Figure 3-9): per pixel, read the SSA entry, read the
//!   start section's fragments and its NSA entry, follow the chain to NULL. The pixel's fragments
//!   are then sorted front to back and composited with the shared OVER
//!   ([`composite::resolve_pixel`]), so the image is the A-buffer's bit for bit. (The thesis composites
//!   with the weight factors of §2.5.2 instead; that resolve is the `wf` method's, which works on
//!   any exact store, and equals OVER only within float rounding.)
//!
//! # Leading-zeros elimination (`options.leading_zeros`)
//!
//! Each fragment's colour loses the leading zero bits common to R, G and B (`tfss::lz`, lossless:
//! the thesis's lossy alpha shift is not applied). A section keeps `L_num` slots but its colour area
//! is sized for components of `b` bits: `area = max(L_num · (8 + 3b), 32)` bits (alpha plus three
//! components per slot, and never less than one full-width record, so any fragment fits an empty
//! section). Records are packed back to back; the Length table entry of each slot says how long
//! its record is, which is what makes the variable-length records readable. A record that does not
//! fit in what is left of the area *seals* the section (code 15), and the fragment moves on to the
//! next section of the chain, so a section holds up to `L_num` fragments and arrival order is kept.
//!
//! `b` is `M_section` in disguise (the section is `64·L_num + area` bits): the thesis evaluates
//! leading-zeros elimination by shrinking `M_section` (Figure 4-5) and leaves what happens to a
//! fragment that does not fit open. [`LzBudget::Auto`] (the default) fits `b` to the frame: after
//! a capture the store counts, from the Length table, exactly how many sections each `b` in 0..=8
//! would need (`model::packed_sections_per_budget`), and if another `b` takes fewer bytes in all —
//! T-buffer, Length table and NSA — and the pool is `Auto`, it captures again with that `b`
//! (reported as a regrow, timed as `capture.refit`). The count walks every chain, about as long as
//! a resolve, so it runs on the first frame of each size and after every pool regrowth (a budget
//! that no longer suits the frames makes more sections seal; once the pool overflows, the budget
//! is fitted again); the frames in between keep the fitted `b`, as an animation's colours change
//! slowly. On our bright scenes colours keep 7.7–7.9 of 8 bits, so the fitted budget is usually
//! 8 and the Length table is pure cost; where most pixels hold fewer fragments than `L_num`, a
//! smaller `b` shrinks the half-empty sections and elimination pays (see `tfss-sim`).
//!
//! # Overflow
//!
//! A fragment that finds no free section is dropped and counted. With [`PoolCapacity::Auto`] (the
//! default) the pool grows and the frame is captured again, as the linked list does. A capacity
//! given in fragments (`PerPixel`, `Fragments`) is converted to sections of `L_num` fragments.
//!
//! # Determinism
//!
//! A pixel's chain holds its fragments in primitive order whatever the thread count; only section
//! addresses depend on scheduling. The resolved image, the DeepFrame and the number of sections
//! used do not.

mod bits;
pub mod lz;
pub mod model;

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};
use std::time::Instant;

use rayon::prelude::*;
use strata_core::fragment::sort_front_to_back;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, ObjectId, PassTimings, Rgb8Image, Rgba8,
    composite,
};
use strata_raster::{CaptureTarget, FragmentSink, FrameInput, Rasterizer, StripLayout};

use crate::alloc::BlockCursor;
use crate::method::{CaptureReport, Method, StoreError, try_alloc};
use crate::options::{MethodOptions, PoolCapacity};
use crate::resolve::resolve_chunks;
use bits::BitArray;
use lz::{LENGTH_BITS, LengthCode};

/// The name TFSS is selected by.
pub const NAME: &str = "tfss";

/// No section: an empty SSA entry, the end of a chain.
pub const NULL: u32 = u32::MAX;

/// Depth bits of an empty plain slot (a NaN; fragments have depths in `[0, 1]`).
const EMPTY_DEPTH: u32 = u32::MAX;

/// The largest pool, in sections (as the linked list's, it leaves the counter room to overshoot).
pub const MAX_SECTIONS: u64 = 1 << 31;

/// The largest `L_num`; larger values are clamped (a section is read with a loop over its slots).
pub const MAX_L_NUM: u32 = 64;

/// Initial pool of [`PoolCapacity::Auto`], in fragments per pixel.
const AUTO_INITIAL_PER_PIXEL: u64 = 2;

/// Colour bits per component a packed section is sized for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LzBudget {
    /// Fit the budget to each frame (see the module docs); the first frame starts at 8.
    Auto,
    /// A fixed budget `b` in `0..=8` (larger values are clamped to 8).
    Bits(u32),
}

/// Where a section's fields are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Geometry {
    /// `L_num`.
    l: u32,
    /// Leading-zeros elimination (the packed format).
    packed: bool,
    /// Packed: bits of the colour area.
    area: u32,
    /// Packed: bits of a whole section.
    bits: u64,
}

impl Geometry {
    fn new(l: u32, packed: bool, rgb_bits: u32) -> Self {
        let area = model::colour_area_bits(l, rgb_bits);
        Geometry {
            l,
            packed,
            area,
            bits: 64 * u64::from(l) + u64::from(area),
        }
    }

    /// Plain: words of a section.
    fn words(&self) -> usize {
        3 * self.l as usize
    }

    /// Length-table bits of a section.
    fn length_bits(&self) -> u64 {
        u64::from(LENGTH_BITS * self.l)
    }

    /// Bytes `n` sections take in the T-buffer (and the Length table, packed), rounded up to
    /// whole bytes over all of them.
    fn section_bytes(&self, n: u64) -> (u64, u64) {
        if self.packed {
            (
                (n * self.bits).div_ceil(8),
                (n * self.length_bits()).div_ceil(8),
            )
        } else {
            (n * self.words() as u64 * 4, 0)
        }
    }
}

/// Byte counts of the TFSS tables; see [`Tfss::memory`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TfssMemory {
    /// `L_num`.
    pub l_num: u32,
    /// The colour budget of a packed section (bits per component); `None` without leading-zeros
    /// elimination.
    pub rgb_bits: Option<u32>,
    /// Bits of one section in the T-buffer (`96 · L_num` plain).
    pub section_bits: u64,
    /// Sections in the pool.
    pub sections_allocated: u64,
    /// Sections holding fragments.
    pub sections_used: u64,
    /// SSA table bytes (`4 · w · h`).
    pub ssa: u64,
    /// T-buffer bytes, allocated.
    pub t_buffer: u64,
    /// T-buffer bytes of the sections used.
    pub t_buffer_used: u64,
    /// NSA table bytes, allocated (`4` per section).
    pub nsa: u64,
    /// NSA bytes of the sections used.
    pub nsa_used: u64,
    /// Length table bytes, allocated (0 without leading-zeros elimination).
    pub length: u64,
    /// Length table bytes of the sections used.
    pub length_used: u64,
}

impl TfssMemory {
    /// Everything allocated, with the 4-byte allocation counter.
    pub fn allocated(&self) -> u64 {
        self.ssa + self.t_buffer + self.nsa + self.length + 4
    }

    /// What holds this frame: SSA, used sections with their NSA and Length entries, the counter.
    pub fn used(&self) -> u64 {
        self.ssa + self.t_buffer_used + self.nsa_used + self.length_used + 4
    }
}

/// The transparent fragment storage system; see the module docs.
#[derive(Debug)]
pub struct Tfss {
    l_num: u32,
    leading_zeros: bool,
    budget: LzBudget,
    rgb_bits: u32,
    pool: PoolCapacity,
    width: u32,
    height: u32,
    ssa: Vec<u32>,
    plain: Vec<AtomicU32>,
    packed: BitArray,
    lengths: BitArray,
    nsa: Vec<AtomicU32>,
    capacity: u32,
    next_free: AtomicU32,
    sections_used: AtomicU64,
    stored: AtomicU64,
    dropped: AtomicU64,
    refits: u32,
    /// The colour budget was fitted since the size or the pool last changed.
    fitted: bool,
    depth: Option<DepthStats>,
}

impl Tfss {
    /// TFSS with `options.l_num` fragments per section (clamped to `1..=`[`MAX_L_NUM`]),
    /// leading-zeros elimination if `options.leading_zeros`, and the pool of `options.pool`.
    pub fn new(options: &MethodOptions) -> Self {
        Tfss {
            l_num: options.l_num.clamp(1, MAX_L_NUM),
            leading_zeros: options.leading_zeros,
            budget: LzBudget::Auto,
            rgb_bits: 8,
            pool: options.pool,
            width: 0,
            height: 0,
            ssa: Vec::new(),
            plain: Vec::new(),
            packed: BitArray::default(),
            lengths: BitArray::default(),
            nsa: Vec::new(),
            capacity: 0,
            next_free: AtomicU32::new(0),
            sections_used: AtomicU64::new(0),
            stored: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            refits: 0,
            fitted: false,
            depth: None,
        }
    }

    /// Sets the colour budget of packed sections (only read with leading-zeros elimination).
    pub fn with_lz_budget(mut self, budget: LzBudget) -> Self {
        self.budget = budget;
        self.rgb_bits = match budget {
            LzBudget::Auto => 8,
            LzBudget::Bits(b) => b.min(8),
        };
        self
    }

    /// `L_num`.
    pub fn l_num(&self) -> u32 {
        self.l_num
    }

    /// Times the last capture refitted the colour budget and captured again (see the module docs
    /// for when the budget is fitted).
    pub fn refits(&self) -> u32 {
        self.refits
    }

    fn geometry(&self) -> Geometry {
        Geometry::new(self.l_num, self.leading_zeros, self.rgb_bits)
    }

    /// The byte counts of every table.
    pub fn memory(&self) -> TfssMemory {
        let g = self.geometry();
        let used = self.sections_used.load(Relaxed);
        let (t_used, l_used) = g.section_bytes(used);
        let (t_buffer, length) = if g.packed {
            (self.packed.bytes(), self.lengths.bytes())
        } else {
            (self.plain.len() as u64 * 4, 0)
        };
        TfssMemory {
            l_num: self.l_num,
            rgb_bits: g.packed.then_some(self.rgb_bits),
            section_bits: if g.packed {
                g.bits
            } else {
                g.words() as u64 * 32
            },
            sections_allocated: u64::from(self.capacity),
            sections_used: used,
            ssa: self.ssa.len() as u64 * 4,
            t_buffer,
            t_buffer_used: t_used,
            nsa: self.nsa.len() as u64 * 4,
            nsa_used: used * 4,
            length,
            length_used: l_used,
        }
    }

    /// The pool size (sections) this frame asks for.
    fn wanted_capacity(&self) -> u64 {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let l = u64::from(self.l_num);
        let n = match self.pool {
            PoolCapacity::Auto => (pixels * AUTO_INITIAL_PER_PIXEL)
                .div_ceil(l)
                .max(u64::from(self.capacity)),
            PoolCapacity::PerPixel(k) => ((pixels as f64 * k).ceil() as u64).div_ceil(l),
            PoolCapacity::Fragments(n) => n.div_ceil(l),
        };
        n.clamp(1, MAX_SECTIONS)
    }

    /// Sizes the pool to `n` sections in the current geometry.
    fn resize_pool(&mut self, n: u64) -> Result<(), StoreError> {
        let n = n.clamp(1, MAX_SECTIONS);
        let g = self.geometry();
        self.capacity = n as u32;
        let nsa_len = n as usize;
        if self.nsa.len() != nsa_len {
            self.nsa = Vec::new();
            self.nsa = try_alloc(
                nsa_len,
                || format!("an NSA table of {n} sections"),
                "give a smaller --pool, or auto",
            )?;
        }
        if g.packed {
            self.plain = Vec::new();
            self.packed.resize(n * g.bits, "a packed T-buffer")?;
            self.lengths.resize(n * g.length_bits(), "a Length table")?;
        } else {
            let words = nsa_len * g.words();
            if self.plain.len() != words {
                self.plain = Vec::new();
                self.plain = try_alloc(
                    words,
                    || format!("a T-buffer of {n} sections of {} fragments", g.l),
                    "give a smaller --pool or --l-num, or auto",
                )?;
            }
        }
        Ok(())
    }

    fn reset(&mut self) {
        self.ssa.par_iter_mut().for_each(|s| *s = NULL);
        self.next_free.store(0, Relaxed);
        self.sections_used.store(0, Relaxed);
        self.stored.store(0, Relaxed);
        self.dropped.store(0, Relaxed);
    }

    fn reader(&self) -> Reader<'_> {
        Reader {
            g: self.geometry(),
            plain: &self.plain,
            packed: &self.packed,
            lengths: &self.lengths,
            nsa: &self.nsa,
        }
    }

    /// The section addresses of row-major pixel `p`'s chain, start section first.
    pub fn chain(&self, p: usize) -> Vec<u32> {
        let mut out = Vec::new();
        let mut s = self.ssa[p];
        while s != NULL {
            out.push(s);
            s = self.nsa[s as usize].load(Relaxed);
        }
        out
    }

    /// Row-major pixel `p`'s fragments in storage order: the chain's sections in order, each
    /// section's slots in order — the arrival order.
    pub fn fragments(&self, p: usize) -> Vec<Fragment> {
        let mut out = Vec::new();
        self.reader().gather(self.ssa[p], &mut out);
        out
    }

    /// Fragments per section along pixel `p`'s chain.
    pub fn section_fill(&self, p: usize) -> Vec<u32> {
        let r = self.reader();
        self.chain(p).iter().map(|&s| r.section_len(s)).collect()
    }

    /// Sections each colour budget `b = 0..=8` would need for the captured frame (packed format,
    /// fragments in arrival order), from the Length table.
    fn sections_per_budget(&self) -> [u64; 9] {
        let r = self.reader();
        let l = self.l_num;
        self.ssa
            .par_iter()
            .with_min_len(1024)
            .fold(
                || ([0u64; 9], Vec::<u8>::new()),
                |(mut acc, mut lens), &start| {
                    if start != NULL {
                        lens.clear();
                        r.lengths_of(start, &mut lens);
                        if lens.len() == 1 {
                            acc.iter_mut().for_each(|a| *a += 1);
                        } else {
                            let per_b = model::packed_sections_per_budget(lens.iter().copied(), l);
                            for (a, n) in acc.iter_mut().zip(per_b) {
                                *a += n;
                            }
                        }
                    }
                    (acc, lens)
                },
            )
            .map(|(acc, _)| acc)
            .reduce(
                || [0u64; 9],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            )
    }

    /// Picks the colour budget with the fewest bytes for this frame; `Some((b, sections))` if it
    /// differs from the current one and saves bytes.
    fn refit(&self) -> Option<(u32, u64)> {
        let per_b = self.sections_per_budget();
        debug_assert_eq!(
            per_b[self.rgb_bits as usize],
            self.sections_used.load(Relaxed),
            "the model's packing is the store's"
        );
        let cost = |b: u32| {
            let g = Geometry::new(self.l_num, true, b);
            per_b[b as usize] * (g.bits + g.length_bits() + 32)
        };
        // The cheapest; among equals the widest (fewest seals).
        let best = (0..=8u32).rev().min_by_key(|&b| cost(b))?;
        (best != self.rgb_bits && cost(best) < cost(self.rgb_bits))
            .then_some((best, per_b[best as usize]))
    }
}

/// Reads sections (shared by resolve, export and the refit).
#[derive(Clone, Copy)]
struct Reader<'a> {
    g: Geometry,
    plain: &'a [AtomicU32],
    packed: &'a BitArray,
    lengths: &'a BitArray,
    nsa: &'a [AtomicU32],
}

impl Reader<'_> {
    /// Appends the fragments of the chain starting at `s`.
    #[inline]
    fn gather(&self, mut s: u32, out: &mut Vec<Fragment>) {
        while s != NULL {
            self.read_section(s, out);
            s = self.nsa[s as usize].load(Relaxed);
        }
    }

    #[inline]
    fn read_section(&self, s: u32, out: &mut Vec<Fragment>) {
        let l = self.g.l as usize;
        if !self.g.packed {
            let base = s as usize * self.g.words();
            let words = &self.plain[base..base + 3 * l];
            for i in 0..l {
                let depth = words[i].load(Relaxed);
                if depth == EMPTY_DEPTH {
                    break;
                }
                out.push(Fragment {
                    depth: f32::from_bits(depth),
                    color: Rgba8::from_bits(words[l + i].load(Relaxed)),
                    object: ObjectId(words[2 * l + i].load(Relaxed)),
                });
            }
            return;
        }
        let lbase = u64::from(s) * self.g.length_bits();
        let sbase = u64::from(s) * self.g.bits;
        let mut off = 64 * self.g.l as u64;
        for i in 0..l as u64 {
            let LengthCode::Stored(len) =
                LengthCode::from_bits(self.lengths.read(lbase + 4 * i, LENGTH_BITS))
            else {
                break;
            };
            let n = lz::record_bits(len);
            let rec = self.packed.read(sbase + off, n);
            off += u64::from(n);
            let [r, g, b] = lz::unpack_rgb(len, (rec >> 8) as u32);
            out.push(Fragment {
                depth: f32::from_bits(self.packed.read(sbase + 32 * i, 32) as u32),
                color: Rgba8([r, g, b, rec as u8]),
                object: ObjectId(self.packed.read(sbase + 32 * (self.g.l as u64 + i), 32) as u32),
            });
        }
    }

    /// Fragments in section `s`.
    fn section_len(&self, s: u32) -> u32 {
        let l = self.g.l;
        if !self.g.packed {
            let base = s as usize * self.g.words();
            return (0..l as usize)
                .take_while(|&i| self.plain[base + i].load(Relaxed) != EMPTY_DEPTH)
                .count() as u32;
        }
        let lbase = u64::from(s) * self.g.length_bits();
        (0..u64::from(l))
            .take_while(|&i| {
                matches!(
                    LengthCode::from_bits(self.lengths.read(lbase + 4 * i, LENGTH_BITS)),
                    LengthCode::Stored(_)
                )
            })
            .count() as u32
    }

    /// Fragments in the chain starting at `s`.
    fn chain_len(&self, mut s: u32) -> u32 {
        let mut n = 0;
        while s != NULL {
            n += self.section_len(s);
            s = self.nsa[s as usize].load(Relaxed);
        }
        n
    }

    /// Appends the colour lengths of the chain starting at `s` (packed format), from the Length
    /// table.
    fn lengths_of(&self, mut s: u32, out: &mut Vec<u8>) {
        while s != NULL {
            let lbase = u64::from(s) * self.g.length_bits();
            for i in 0..u64::from(self.g.l) {
                match LengthCode::from_bits(self.lengths.read(lbase + 4 * i, LENGTH_BITS)) {
                    LengthCode::Stored(len) => out.push(len as u8),
                    _ => break,
                }
            }
            s = self.nsa[s as usize].load(Relaxed);
        }
    }
}

/// Capture into one strip of rows.
#[derive(Debug)]
pub struct TfssSink<'a> {
    ssa: &'a mut [u32],
    first_pixel: u32,
    g: Geometry,
    plain: &'a [AtomicU32],
    packed: &'a BitArray,
    lengths: &'a BitArray,
    nsa: &'a [AtomicU32],
    capacity: u32,
    next_free: &'a AtomicU32,
    sections_used: &'a AtomicU64,
    stored: &'a AtomicU64,
    dropped: &'a AtomicU64,
    block: BlockCursor,
    /// Sections reserved at a time (`crate::alloc::block_size`), the same for every strip of a
    /// frame, so every block starts at a multiple of it.
    block_size: u32,
    n_sections: u64,
    n_stored: u64,
    n_dropped: u64,
}

impl TfssSink<'_> {
    /// A new empty section, its NSA entry NULL; `None` when the pool is exhausted.
    #[inline]
    fn allocate(&mut self) -> Option<u32> {
        let block = self.block_size;
        let s = self.block.next(self.next_free, self.capacity, block)?;
        let g = self.g;
        if g.packed {
            if s % block == 0 {
                // A fresh block: zero its words (they may hold an earlier frame's sections).
                let (a, b) = (u64::from(s), u64::from((s + block).min(self.capacity)));
                self.packed.zero_words(a * g.bits, b * g.bits);
                let lb = g.length_bits();
                self.lengths.zero_words(a * lb, b * lb);
            }
        } else {
            let base = s as usize * g.words();
            for w in &self.plain[base..base + g.l as usize] {
                w.store(EMPTY_DEPTH, Relaxed);
            }
        }
        self.nsa[s as usize].store(NULL, Relaxed);
        self.n_sections += 1;
        Some(s)
    }

    /// Stores `f` in section `s` if it has room (packed: `len`/`rgb` are its packed colour).
    #[inline(always)]
    fn try_put(&self, s: u32, f: Fragment, len: u32, rgb: u32) -> bool {
        let g = self.g;
        let l = g.l as usize;
        if !g.packed {
            let base = s as usize * g.words();
            let words = &self.plain[base..base + 3 * l];
            for i in 0..l {
                if words[i].load(Relaxed) == EMPTY_DEPTH {
                    words[i].store(f.depth.to_bits(), Relaxed);
                    words[l + i].store(f.color.to_bits(), Relaxed);
                    words[2 * l + i].store(f.object.0, Relaxed);
                    return true;
                }
            }
            return false;
        }
        let lbase = u64::from(s) * g.length_bits();
        let sbase = u64::from(s) * g.bits;
        let mut used = 0u32;
        for i in 0..l as u64 {
            let at = lbase + 4 * i;
            match LengthCode::from_bits(self.lengths.read(at, LENGTH_BITS)) {
                LengthCode::Stored(n) => used += lz::record_bits(n),
                LengthCode::Sealed => return false,
                LengthCode::Empty => {
                    let n = lz::record_bits(len);
                    if used + n > g.area {
                        self.lengths
                            .or(at, LENGTH_BITS, LengthCode::Sealed.to_bits());
                        return false;
                    }
                    self.packed
                        .or(sbase + 32 * i, 32, u64::from(f.depth.to_bits()));
                    self.packed
                        .or(sbase + 32 * (g.l as u64 + i), 32, u64::from(f.object.0));
                    let record = u64::from(f.color.alpha()) | (u64::from(rgb) << 8);
                    self.packed
                        .or(sbase + 64 * g.l as u64 + u64::from(used), n, record);
                    self.lengths
                        .or(at, LENGTH_BITS, LengthCode::Stored(len).to_bits());
                    return true;
                }
            }
        }
        false
    }
}

impl FragmentSink for TfssSink<'_> {
    #[inline]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        debug_assert_ne!(fragment.depth.to_bits(), EMPTY_DEPTH);
        let (len, rgb) = if self.g.packed {
            let [r, g, b, _] = fragment.color.0;
            lz::pack_rgb([r, g, b])
        } else {
            (0, 0)
        };
        let local = (pixel - self.first_pixel) as usize;
        // Read the SSA entry, then walk the chain to the first section with room. Sections are
        // linked only when full (or sealed), so that is the last one: the walk reads NSA entries
        // only, and the T-buffer of the last section.
        let mut s = self.ssa[local];
        if s != NULL {
            loop {
                match self.nsa[s as usize].load(Relaxed) {
                    NULL => break,
                    next => s = next,
                }
            }
            if self.try_put(s, fragment, len, rgb) {
                self.n_stored += 1;
                return;
            }
        }
        // No start section, or every section of the chain is full: allocate a new one and record
        // it in the SSA table or in the last section's NSA entry.
        let Some(new) = self.allocate() else {
            self.n_dropped += 1;
            return;
        };
        if s == NULL {
            self.ssa[local] = new;
        } else {
            self.nsa[s as usize].store(new, Relaxed);
        }
        let stored = self.try_put(new, fragment, len, rgb);
        debug_assert!(stored, "an empty section holds any fragment");
        self.n_stored += 1;
    }

    fn finish(&mut self) {
        self.sections_used.fetch_add(self.n_sections, Relaxed);
        self.stored.fetch_add(self.n_stored, Relaxed);
        self.dropped.fetch_add(self.n_dropped, Relaxed);
    }
}

impl CaptureTarget for Tfss {
    type Sink<'s> = TfssSink<'s>;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<TfssSink<'_>> {
        assert_eq!(
            (layout.width, layout.height),
            (self.width, self.height),
            "clear before capture"
        );
        let g = self.geometry();
        let capacity = self.capacity;
        let (plain, packed, lengths, nsa) =
            (&self.plain[..], &self.packed, &self.lengths, &self.nsa[..]);
        let (next_free, sections_used, stored, dropped) = (
            &self.next_free,
            &self.sections_used,
            &self.stored,
            &self.dropped,
        );
        let block_size = crate::alloc::block_size(capacity as usize, layout.count());
        layout
            .split_mut(&mut self.ssa)
            .enumerate()
            .map(|(s, ssa)| TfssSink {
                ssa,
                first_pixel: layout.pixels(s).start as u32,
                g,
                plain,
                packed,
                lengths,
                nsa,
                capacity,
                next_free,
                sections_used,
                stored,
                dropped,
                block: BlockCursor::default(),
                block_size,
                n_sections: 0,
                n_stored: 0,
                n_dropped: 0,
            })
            .collect()
    }
}

impl Method for Tfss {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        assert!(
            (pixels as u64) < u64::from(NULL),
            "image too large for u32 pixel indices"
        );
        (self.width, self.height) = (width, height);
        if self.ssa.len() != pixels {
            self.ssa = Vec::new();
            self.ssa = try_alloc::<u32>(
                pixels,
                || format!("an SSA table of {pixels} entries"),
                "render a smaller image",
            )?;
            self.fitted = false;
        }
        self.resize_pool(self.wanted_capacity())?;
        self.reset();
        self.refits = 0;
        self.depth = None;
        Ok(())
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let strips = prepared.layout().count();
        let auto = self.pool == PoolCapacity::Auto;
        let mut regrows = 0;
        let mut passes = 0;
        loop {
            let start = Instant::now();
            let stats = prepared.rasterize(self);
            passes += 1;
            timings.add("capture.raster", start.elapsed());
            let dropped = self.dropped.load(Relaxed);
            if dropped > 0 && auto && u64::from(self.capacity) < MAX_SECTIONS {
                // Grow to the sections this frame needs, extrapolated from what was stored, plus
                // each strip's unused block tail, with headroom for the next frames.
                let start = Instant::now();
                let (used, stored) = (
                    self.sections_used.load(Relaxed),
                    self.stored.load(Relaxed).max(1),
                );
                let need = (used as f64 * stats.fragments as f64 / stored as f64).ceil() as u64;
                let grown = (crate::alloc::capacity_for(need, strips) * 5 / 4)
                    .max(u64::from(self.capacity) * 5 / 4 + 1);
                self.resize_pool(grown)?;
                self.reset();
                regrows += 1;
                self.fitted = false;
                timings.add("capture.regrow", start.elapsed());
                continue;
            }
            if dropped == 0
                && auto
                && !self.fitted
                && self.leading_zeros
                && self.budget == LzBudget::Auto
            {
                let start = Instant::now();
                self.fitted = true;
                let refit = self.refit();
                if let Some((b, sections)) = refit {
                    self.rgb_bits = b;
                    let fit = crate::alloc::capacity_for(sections, strips) * 5 / 4;
                    self.resize_pool(fit.max(u64::from(self.capacity)))?;
                    self.reset();
                    regrows += 1;
                    self.refits += 1;
                }
                timings.add("capture.refit", start.elapsed());
                if refit.is_some() {
                    continue;
                }
            }
            return Ok(CaptureReport {
                fragments_rasterized: stats.fragments,
                fragments_stored: self.stored.load(Relaxed),
                dropped,
                regrows,
                raster_passes: passes,
                setup: prepared.setup_stats(),
                ..CaptureReport::default()
            });
        }
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let bg = composite::background_pixel(background);
        let (reader, ssa) = (self.reader(), &self.ssa[..]);
        let (image, depth) = resolve_chunks(
            self.width,
            self.height,
            || Vec::with_capacity(32),
            |list, first, out, stats| {
                for (i, px) in out.chunks_exact_mut(3).enumerate() {
                    let start = ssa[first + i];
                    if start == NULL {
                        px.copy_from_slice(&bg);
                        stats.record(0);
                        continue;
                    }
                    list.clear();
                    reader.gather(start, list);
                    stats.record(list.len() as u32);
                    sort_front_to_back(list);
                    px.copy_from_slice(&composite::resolve_pixel(
                        list.iter().map(|f| f.color),
                        background,
                    ));
                }
            },
        );
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn memory_bytes(&self) -> u64 {
        self.memory().allocated()
    }

    fn used_memory_bytes(&self) -> u64 {
        self.memory().used()
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        let reader = self.reader();
        let counts: Vec<u32> = self.ssa.par_iter().map(|&s| reader.chain_len(s)).collect();
        Some(DeepFrame::build(
            self.width,
            self.height,
            &counts,
            |p, out| reader.gather(self.ssa[p], out),
        ))
    }
}

#[cfg(test)]
mod tests;
