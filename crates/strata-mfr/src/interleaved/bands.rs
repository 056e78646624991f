//! The SC frame's export in bands of rows, spread over FC periods.
//!
//! ```text
//! store (every fragment of the frame) ──rows 0..r₁──▶ band DeepFrame ──append──▶ frame  (rows so far)
//!                                     ──rows r₁..r₂─▶ band DeepFrame ──resolve─▶ image  (bytes so far)
//!                                     …                              └─count──▶ fragments per object
//! ```
//!
//! Each band is exported from the store ([`Client::export_rows`]: count, prefix-sum, gather and
//! sort its pixels' lists), resolved onto the background, and appended below the rows done
//! before ([`DeepFrame::append_rows`], the image's bytes likewise). Every pixel's run and colour
//! depend on that pixel's list only, so the bands of any split assemble the frame and image of a
//! one-piece export, bit for bit. The band's object column is counted on the way: the next SC
//! frame's chunk estimate uses the fragments each object made ([`super::estimate`]).

use strata_core::{DeepFrame, Rgb8Image};

use super::estimate::ObjectFragments;
use crate::client::{Client, ClientError};

/// An export in progress: the rows done so far, assembled.
#[derive(Debug)]
pub struct BandedExport {
    width: u32,
    height: u32,
    background: [f32; 3],
    frame: DeepFrame,
    image: Vec<u8>,
    objects: ObjectFragments,
}

impl BandedExport {
    /// An export of `client`'s frame, no row done yet, resolving onto `background`.
    pub fn new(client: &Client, background: [f32; 3]) -> Self {
        let (width, height) = client.size();
        BandedExport {
            width,
            height,
            background,
            frame: DeepFrame::empty(width, 0),
            image: Vec::with_capacity(width as usize * height as usize * 3),
            objects: ObjectFragments::default(),
        }
    }

    /// Makes room for a frame of `fragments` fragments (the previous frame's count, say), so
    /// that no band moves what the bands before it assembled.
    pub fn reserve(&mut self, fragments: usize) {
        let pixels = self.width as usize * self.height as usize;
        self.frame.reserve(fragments, pixels);
    }

    /// Rows done.
    pub fn rows_done(&self) -> u32 {
        self.frame.height()
    }

    /// Rows left.
    pub fn rows_left(&self) -> u32 {
        self.height - self.rows_done()
    }

    /// Exports, resolves and appends the next `rows` rows (fewer when fewer are left).
    ///
    /// # Errors
    /// The store cannot export them.
    pub fn step(&mut self, client: &Client, rows: u32) -> Result<(), ClientError> {
        let start = self.rows_done();
        let end = start + rows.min(self.rows_left());
        let band = client.export_rows(start..end)?;
        self.image
            .extend_from_slice(band.resolve(self.background).as_bytes());
        self.objects.add(band.objects());
        self.frame
            .append_rows(&band)
            .map_err(|e| ClientError::DeepFrame(e.to_string()))
    }

    /// Whether every row is done.
    pub fn is_done(&self) -> bool {
        self.rows_left() == 0
    }

    /// The assembled frame and its image.
    ///
    /// # Errors
    /// Rows are left to export.
    pub fn finish(self) -> Result<(DeepFrame, Rgb8Image), ClientError> {
        Ok(self.finish_counted()?.0)
    }

    /// The assembled frame, its image and the fragments per object id.
    pub(crate) fn finish_counted(
        self,
    ) -> Result<((DeepFrame, Rgb8Image), ObjectFragments), ClientError> {
        if !self.is_done() {
            return Err(ClientError::DeepFrame(format!(
                "the export in bands stopped at row {} of {}",
                self.rows_done(),
                self.height
            )));
        }
        let image = Rgb8Image::from_raw(self.width, self.height, self.image).ok_or_else(|| {
            ClientError::DeepFrame("the bands' images do not fill the frame".into())
        })?;
        Ok(((self.frame, image), self.objects))
    }
}
