//! The fast client's fragments, kept for the rectangle its objects cover.
//!
//! # Layout
//!
//! A [`DeepWindow`] is a DeepFrame the size of a [`PixelRect`] of the full frame, plus where that
//! rectangle lies: pixel `q` of the window (row-major within it) is pixel
//! `rect.frame_index(q, frame_width)` of the frame. Every fragment the FC rendered is inside
//! (the client checks, and falls back to the whole frame when its guess of the footprint was
//! short), so the full frame is the window padded with empty pixels ([`DeepWindow::to_full`]).
//!
//! Exporting, handing over and compositing a window cost what the FC's objects cover; a
//! full-frame DeepFrame would cost a pass over every pixel of the screen each FC frame.

use strata_core::{DeepFrame, DeepFrameError, PixelRect, Rgb8Image, Run};

/// Fragments of a rectangle of a `frame_width × frame_height` frame; none outside it.
#[derive(Clone, Debug, PartialEq)]
pub struct DeepWindow {
    rect: PixelRect,
    frame_width: u32,
    frame_height: u32,
    frame: DeepFrame,
}

impl DeepWindow {
    /// `frame` (the rectangle's size) placed at `rect` of a `frame_width × frame_height` frame.
    ///
    /// # Errors
    /// When the frame is not the rectangle's size or the rectangle does not fit.
    pub fn new(
        rect: PixelRect,
        (frame_width, frame_height): (u32, u32),
        frame: DeepFrame,
    ) -> Result<Self, DeepFrameError> {
        if !rect.fits(frame_width, frame_height)
            || frame.width() != rect.width
            || frame.height() != rect.height
        {
            return Err(DeepFrameError::PixelCount {
                width: rect.width,
                height: rect.height,
                expected: rect.pixel_count() as u64,
                found: u64::from(frame.width()) * u64::from(frame.height()),
            });
        }
        Ok(DeepWindow {
            rect,
            frame_width,
            frame_height,
            frame,
        })
    }

    /// A whole frame as a window.
    pub fn whole(frame: DeepFrame) -> Self {
        DeepWindow {
            rect: PixelRect::full(frame.width(), frame.height()),
            frame_width: frame.width(),
            frame_height: frame.height(),
            frame,
        }
    }

    /// Where the window lies.
    pub fn rect(&self) -> PixelRect {
        self.rect
    }

    /// The full frame's width and height.
    pub fn frame_size(&self) -> (u32, u32) {
        (self.frame_width, self.frame_height)
    }

    /// The window's fragments (a frame the rectangle's size).
    pub fn frame(&self) -> &DeepFrame {
        &self.frame
    }

    /// The run of frame pixel `(x, y)`: empty outside the window.
    pub fn run_at(&self, x: u32, y: u32) -> Option<Run<'_>> {
        let r = self.rect;
        let inside = x >= r.x && y >= r.y && x - r.x < r.width && y - r.y < r.height;
        inside.then(|| self.frame.run(((y - r.y) * r.width + (x - r.x)) as usize))
    }

    /// Fragments held.
    pub fn fragment_count(&self) -> u64 {
        self.frame.fragment_count() as u64
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        self.frame.memory_bytes()
    }

    /// The full frame resolved onto `background`: the window's pixels resolved, the others the
    /// background. Equal to `self.to_full()?.resolve(background)` without building the frame.
    pub fn resolve(&self, background: [f32; 3]) -> Rgb8Image {
        let bg = strata_core::composite::background_pixel(background);
        let mut image = Rgb8Image::filled(self.frame_width, self.frame_height, bg);
        let part = self.frame.resolve(background);
        let (r, w) = (self.rect, self.frame_width as usize);
        let row = 3 * r.width as usize;
        for j in 0..r.height as usize {
            let at = 3 * ((r.y as usize + j) * w + r.x as usize);
            image.as_bytes_mut()[at..at + row]
                .copy_from_slice(&part.as_bytes()[j * row..(j + 1) * row]);
        }
        image
    }

    /// The full frame: the window padded with empty pixels.
    ///
    /// # Errors
    /// Only when the frame would hold more fragments than a DeepFrame can (it cannot: the
    /// window holds them already).
    pub fn to_full(&self) -> Result<DeepFrame, DeepFrameError> {
        if self.rect == PixelRect::full(self.frame_width, self.frame_height) {
            return Ok(self.frame.clone());
        }
        let r = self.rect;
        let mut counts =
            vec![0u32; PixelRect::full(self.frame_width, self.frame_height).pixel_count()];
        let mut window_of = vec![usize::MAX; counts.len()];
        for q in 0..r.pixel_count() {
            let p = r.frame_index(q, self.frame_width);
            counts[p] = self.frame.run(q).len() as u32;
            window_of[p] = q;
        }
        DeepFrame::build(self.frame_width, self.frame_height, &counts, |p, out| {
            out.extend(self.frame.run(window_of[p]).iter());
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, ObjectId, Rgba8};

    fn frag(depth: f32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([10, 20, 30, 128]),
            object: ObjectId(1),
        }
    }

    #[test]
    fn a_window_pads_to_the_full_frame() {
        let rect = PixelRect {
            x: 1,
            y: 2,
            width: 2,
            height: 1,
        };
        let part =
            DeepFrame::from_pixel_lists(2, 1, &[vec![frag(0.5)], vec![frag(0.2), frag(0.7)]])
                .expect("window");
        let w = DeepWindow::new(rect, (4, 3), part).expect("fits");
        let mut lists = vec![Vec::new(); 12];
        lists[9] = vec![frag(0.5)];
        lists[10] = vec![frag(0.2), frag(0.7)];
        let full = DeepFrame::from_pixel_lists(4, 3, &lists).expect("full");
        assert_eq!(w.to_full().expect("full"), full);
        let bg = [0.2, 0.4, 0.9];
        assert_eq!(w.resolve(bg), full.resolve(bg));
        assert_eq!(w.run_at(2, 2).map(|r| r.len()), Some(2));
        assert!(w.run_at(0, 2).is_none() && w.run_at(1, 1).is_none() && w.run_at(3, 2).is_none());
        assert_eq!(
            DeepWindow::whole(full.clone()).to_full().expect("same"),
            full
        );
        // A window that does not fit, or a frame of the wrong size, is refused.
        let part = DeepFrame::from_pixel_lists(2, 1, &[vec![], vec![]]).expect("window");
        assert!(DeepWindow::new(rect, (2, 3), part.clone()).is_err());
        assert!(DeepWindow::new(PixelRect { width: 3, ..rect }, (4, 3), part).is_err());
    }
}
