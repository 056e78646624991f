//! The in-memory images: [`DeepImage`] (per-pixel sample lists) and [`FlatImage`] (one value per
//! pixel and channel), with the channel, window and attribute types they share.
//!
//! Both keep one column per channel, channels sorted by name as OpenEXR stores them:
//!
//! ```text
//! DeepImage                                   FlatImage
//! offsets: [u32; w*h + 1]  prefix sum         (none)
//! columns[c]: [T; offsets[w*h]]               columns[c]: [T; w*h]
//!   pixel p = (y - y_min) * w + (x - x_min)     pixel p, row-major from the top
//!   owns samples offsets[p] .. offsets[p+1]
//! ```
//!
//! `T` is `f32` for `HALF` and `FLOAT` channels (the declared [`SampleType`] says how it is
//! written) and `u32` for `UINT` channels.

use crate::error::{ExrError, Result};

/// How one channel's samples are stored in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SampleType {
    /// 32-bit unsigned integer (object ids).
    Uint,
    /// 16-bit IEEE float.
    Half,
    /// 32-bit IEEE float.
    Float,
}

impl SampleType {
    /// The code OpenEXR's channel list uses (0, 1, 2).
    pub fn code(self) -> i32 {
        match self {
            SampleType::Uint => 0,
            SampleType::Half => 1,
            SampleType::Float => 2,
        }
    }

    /// The type for an OpenEXR channel-list code.
    pub fn from_code(code: i32) -> Option<Self> {
        match code {
            0 => Some(SampleType::Uint),
            1 => Some(SampleType::Half),
            2 => Some(SampleType::Float),
            _ => None,
        }
    }

    /// Bytes per sample in the file.
    pub fn bytes(self) -> usize {
        match self {
            SampleType::Half => 2,
            SampleType::Uint | SampleType::Float => 4,
        }
    }

    /// The OpenEXR name, as `exrheader` prints it.
    pub fn name(self) -> &'static str {
        match self {
            SampleType::Uint => "uint",
            SampleType::Half => "half",
            SampleType::Float => "float",
        }
    }
}

/// A named channel and how its samples are stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Channel {
    /// The channel name (`R`, `A`, `Z`, `objectid`, `diffuse.R`, …).
    pub name: String,
    /// The stored sample type.
    pub sample_type: SampleType,
}

impl Channel {
    /// A channel.
    pub fn new(name: impl Into<String>, sample_type: SampleType) -> Self {
        Channel {
            name: name.into(),
            sample_type,
        }
    }
}

/// One channel's values: floats for `HALF`/`FLOAT` channels, integers for `UINT` channels.
#[derive(Clone, Debug, PartialEq)]
pub enum Column {
    /// Values of a `HALF` or `FLOAT` channel.
    F32(Vec<f32>),
    /// Values of a `UINT` channel.
    U32(Vec<u32>),
}

impl Column {
    /// Number of values.
    pub fn len(&self) -> usize {
        match self {
            Column::F32(v) => v.len(),
            Column::U32(v) => v.len(),
        }
    }

    /// True if the column holds no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// An empty column for a sample type, with room for `capacity` values.
    pub fn with_capacity(sample_type: SampleType, capacity: usize) -> Self {
        match sample_type {
            SampleType::Uint => Column::U32(Vec::with_capacity(capacity)),
            SampleType::Half | SampleType::Float => Column::F32(Vec::with_capacity(capacity)),
        }
    }

    /// The value at `i` as `f64` (integers converted), or `None` past the end.
    pub fn get_f64(&self, i: usize) -> Option<f64> {
        match self {
            Column::F32(v) => v.get(i).map(|&x| f64::from(x)),
            Column::U32(v) => v.get(i).map(|&x| f64::from(x)),
        }
    }

    /// The float values, or `None` for a `UINT` column.
    pub fn as_f32(&self) -> Option<&[f32]> {
        match self {
            Column::F32(v) => Some(v),
            Column::U32(_) => None,
        }
    }

    /// The integer values, or `None` for a float column.
    pub fn as_u32(&self) -> Option<&[u32]> {
        match self {
            Column::U32(v) => Some(v),
            Column::F32(_) => None,
        }
    }

    fn matches(&self, sample_type: SampleType) -> bool {
        matches!(
            (self, sample_type),
            (Column::U32(_), SampleType::Uint)
                | (Column::F32(_), SampleType::Half | SampleType::Float)
        )
    }
}

/// An integer rectangle with inclusive corners, OpenEXR's `box2i`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Box2i {
    /// Left column.
    pub x_min: i32,
    /// Top row.
    pub y_min: i32,
    /// Right column (inclusive).
    pub x_max: i32,
    /// Bottom row (inclusive).
    pub y_max: i32,
}

impl Box2i {
    /// The `width`×`height` window with its top-left corner at `(x, y)`.
    ///
    /// # Errors
    /// [`ExrError::InvalidImage`] if the window is empty or its corner overflows `i32`.
    pub fn from_origin(x: i32, y: i32, width: u32, height: u32) -> Result<Self> {
        let end = |start: i32, len: u32| -> Option<i32> {
            let len = i32::try_from(len).ok().filter(|&l| l > 0)?;
            start.checked_add(len - 1)
        };
        match (end(x, width), end(y, height)) {
            (Some(x_max), Some(y_max)) => Ok(Box2i {
                x_min: x,
                y_min: y,
                x_max,
                y_max,
            }),
            _ => Err(ExrError::InvalidImage(format!(
                "a {width}x{height} window at ({x}, {y}) is empty or does not fit in 32-bit coordinates"
            ))),
        }
    }

    /// Width in pixels (0 if the box is empty).
    pub fn width(&self) -> u64 {
        (i64::from(self.x_max) - i64::from(self.x_min) + 1).max(0) as u64
    }

    /// Height in pixels (0 if the box is empty).
    pub fn height(&self) -> u64 {
        (i64::from(self.y_max) - i64::from(self.y_min) + 1).max(0) as u64
    }

    /// `width * height`.
    pub fn pixel_count(&self) -> u64 {
        self.width().saturating_mul(self.height())
    }

    /// True if `(x, y)` lies inside.
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= i64::from(self.x_min)
            && x <= i64::from(self.x_max)
            && y >= i64::from(self.y_min)
            && y <= i64::from(self.y_max)
    }

    /// The smallest box holding both.
    pub fn union(&self, other: &Box2i) -> Box2i {
        Box2i {
            x_min: self.x_min.min(other.x_min),
            y_min: self.y_min.min(other.y_min),
            x_max: self.x_max.max(other.x_max),
            y_max: self.y_max.max(other.y_max),
        }
    }
}

/// A header attribute strata does not interpret, kept byte for byte so that a foreign file's
/// metadata survives a read and a write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Attribute {
    /// The attribute name.
    pub name: String,
    /// The OpenEXR type name (`string`, `float`, `m44f`, …).
    pub type_name: String,
    /// The value exactly as stored (little-endian).
    pub value: Vec<u8>,
}

impl Attribute {
    /// A `string` attribute.
    pub fn string(name: &str, value: &str) -> Self {
        Attribute {
            name: name.to_owned(),
            type_name: "string".to_owned(),
            value: value.as_bytes().to_vec(),
        }
    }

    /// A `float` attribute.
    pub fn float(name: &str, value: f32) -> Self {
        Attribute {
            name: name.to_owned(),
            type_name: "float".to_owned(),
            value: value.to_le_bytes().to_vec(),
        }
    }

    /// A `double` attribute.
    pub fn double(name: &str, value: f64) -> Self {
        Attribute {
            name: name.to_owned(),
            type_name: "double".to_owned(),
            value: value.to_le_bytes().to_vec(),
        }
    }

    /// An `m44f` attribute from a row-major 4×4 matrix (OpenEXR's Imath layout: `m[row][col]`,
    /// translation in the last row).
    pub fn m44f(name: &str, value: [f32; 16]) -> Self {
        Attribute {
            name: name.to_owned(),
            type_name: "m44f".to_owned(),
            value: value.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    /// The value of a `float` attribute.
    pub fn as_float(&self) -> Option<f32> {
        (self.type_name == "float")
            .then(|| {
                self.value
                    .as_slice()
                    .try_into()
                    .ok()
                    .map(f32::from_le_bytes)
            })
            .flatten()
    }

    /// The value of a `double` attribute.
    pub fn as_double(&self) -> Option<f64> {
        (self.type_name == "double")
            .then(|| {
                self.value
                    .as_slice()
                    .try_into()
                    .ok()
                    .map(f64::from_le_bytes)
            })
            .flatten()
    }

    /// The value of a `string` attribute, if it is UTF-8.
    pub fn as_string(&self) -> Option<&str> {
        (self.type_name == "string")
            .then(|| std::str::from_utf8(&self.value).ok())
            .flatten()
    }
}

impl std::fmt::Display for Attribute {
    /// The value as `exrheader` would show it for common types (`string`, `int`, `float`,
    /// `double`, `v2f`, `v2i`, `box2i`, `box2f`, `m44f`, `compression`, `lineOrder`, `chlist`), else
    /// its type and size.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = &self.value;
        let i32s = || {
            v.chunks_exact(4)
                .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let f32s = || {
            v.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let list = |items: Vec<String>| items.join(" ");
        match (self.type_name.as_str(), v.len()) {
            ("string", _) => write!(f, "{:?}", String::from_utf8_lossy(v)),
            ("int", 4) => write!(f, "{}", list(i32s().map(|x| x.to_string()).collect())),
            ("float", 4) | ("v2f", 8) => {
                write!(f, "{}", list(f32s().map(|x| x.to_string()).collect()))
            }
            ("v2i", 8) => write!(f, "{}", list(i32s().map(|x| x.to_string()).collect())),
            ("double", 8) => write!(f, "{}", self.as_double().unwrap_or(f64::NAN)),
            ("box2i", 16) => {
                let b: Vec<i32> = i32s().collect();
                write!(f, "({} {}) - ({} {})", b[0], b[1], b[2], b[3])
            }
            ("box2f", 16) => {
                let b: Vec<f32> = f32s().collect();
                write!(f, "({} {}) - ({} {})", b[0], b[1], b[2], b[3])
            }
            ("m44f", 64) => {
                let rows: Vec<String> = f32s()
                    .collect::<Vec<_>>()
                    .chunks(4)
                    .map(|r| format!("[{}]", list(r.iter().map(|x| x.to_string()).collect())))
                    .collect();
                write!(f, "{}", rows.join(" "))
            }
            ("compression", 1) => write!(
                f,
                "{}",
                crate::compress::Compression::ALL
                    .iter()
                    .find(|c| c.code() == v[0])
                    .map_or_else(|| crate::compress::unsupported_name(v[0]), |c| c.name())
            ),
            ("lineOrder", 1) => write!(
                f,
                "{}",
                match v[0] {
                    0 => "increasing y",
                    1 => "decreasing y",
                    2 => "random y",
                    _ => "unknown",
                }
            ),
            ("chlist", _) => match crate::header::parse_channels(self) {
                Ok(channels) => {
                    let items: Vec<String> = channels
                        .iter()
                        .map(|c| format!("{} ({})", c.name, c.sample_type.name()))
                        .collect();
                    write!(f, "{}", items.join(", "))
                }
                Err(e) => write!(f, "<invalid channel list: {e}>"),
            },
            (t, n) => write!(f, "<{t}, {n} bytes>"),
        }
    }
}

/// Checks channel names: at least one channel; names non-empty, at most 255 bytes, no NUL,
/// strictly ascending (unique).
pub(crate) fn check_channels(channels: &[Channel]) -> Result<()> {
    if channels.is_empty() {
        return Err(ExrError::InvalidImage(
            "an image needs at least one channel".into(),
        ));
    }
    for c in channels {
        if c.name.is_empty() || c.name.len() > 255 || c.name.contains('\0') {
            return Err(ExrError::InvalidImage(format!(
                "channel name {:?} must be 1 to 255 bytes without NUL",
                c.name
            )));
        }
    }
    for pair in channels.windows(2) {
        if pair[0].name.as_bytes() >= pair[1].name.as_bytes() {
            return Err(ExrError::InvalidImage(format!(
                "channels must be sorted by name and unique; `{}` comes before `{}`",
                pair[0].name, pair[1].name
            )));
        }
    }
    Ok(())
}

fn check_columns(channels: &[Channel], columns: &[Column], len: usize) -> Result<()> {
    if channels.len() != columns.len() {
        return Err(ExrError::InvalidImage(format!(
            "{} channels but {} columns",
            channels.len(),
            columns.len()
        )));
    }
    for (c, col) in channels.iter().zip(columns) {
        if !col.matches(c.sample_type) {
            return Err(ExrError::InvalidImage(format!(
                "channel `{}` is {} but its column holds {}",
                c.name,
                c.sample_type.name(),
                if matches!(col, Column::U32(_)) {
                    "integers"
                } else {
                    "floats"
                }
            )));
        }
        if col.len() != len {
            return Err(ExrError::InvalidImage(format!(
                "channel `{}` holds {} values, expected {len}",
                c.name,
                col.len()
            )));
        }
    }
    Ok(())
}

fn check_window(window: &Box2i) -> Result<usize> {
    if window.width() == 0 || window.height() == 0 {
        return Err(ExrError::InvalidImage(format!(
            "the data window {window:?} is empty"
        )));
    }
    usize::try_from(window.pixel_count())
        .map_err(|_| ExrError::InvalidImage(format!("the data window {window:?} is too large")))
}

/// A deep image: any number of samples per pixel, each with a value in every channel.
///
/// See the module docs for the layout. Constructed by [`DeepImage::new`], which checks that the
/// offsets are a prefix sum, the channels are sorted and every column has one value per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct DeepImage {
    pub(crate) data_window: Box2i,
    pub(crate) display_window: Box2i,
    pub(crate) channels: Vec<Channel>,
    pub(crate) offsets: Vec<u32>,
    pub(crate) columns: Vec<Column>,
    pub(crate) attributes: Vec<Attribute>,
}

impl DeepImage {
    /// A deep image over `data_window` (also its display window) from its parts.
    ///
    /// `channels` must be sorted by name; `offsets` has one entry per pixel plus one, starts at
    /// 0 and never decreases; each column holds `offsets[last]` values of its channel's kind.
    ///
    /// # Errors
    /// [`ExrError::InvalidImage`] naming the first inconsistency.
    pub fn new(
        data_window: Box2i,
        channels: Vec<Channel>,
        offsets: Vec<u32>,
        columns: Vec<Column>,
    ) -> Result<Self> {
        let pixels = check_window(&data_window)?;
        check_channels(&channels)?;
        if offsets.len() != pixels + 1 {
            return Err(ExrError::InvalidImage(format!(
                "{} offsets for {pixels} pixels (expected {})",
                offsets.len(),
                pixels + 1
            )));
        }
        if offsets[0] != 0 {
            return Err(ExrError::InvalidImage("offsets must start at 0".into()));
        }
        if let Some(p) = offsets.windows(2).position(|w| w[1] < w[0]) {
            return Err(ExrError::InvalidImage(format!(
                "offsets decrease at pixel {p}"
            )));
        }
        check_columns(&channels, &columns, offsets[pixels] as usize)?;
        Ok(DeepImage {
            data_window,
            display_window: data_window,
            channels,
            offsets,
            columns,
            attributes: Vec::new(),
        })
    }

    /// The rectangle the pixels cover.
    pub fn data_window(&self) -> Box2i {
        self.data_window
    }

    /// The rectangle of the whole picture (may differ from the data window).
    pub fn display_window(&self) -> Box2i {
        self.display_window
    }

    /// Sets the display window.
    pub fn set_display_window(&mut self, window: Box2i) {
        self.display_window = window;
    }

    /// Width of the data window.
    pub fn width(&self) -> usize {
        self.data_window.width() as usize
    }

    /// Height of the data window.
    pub fn height(&self) -> usize {
        self.data_window.height() as usize
    }

    /// The channels, sorted by name.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The index of the channel called `name`.
    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.name == name)
    }

    /// Per-pixel sample offsets (a prefix sum, `width*height + 1` entries).
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// Column `c` (same order as [`DeepImage::channels`]).
    pub fn column(&self, c: usize) -> &Column {
        &self.columns[c]
    }

    /// All columns.
    pub fn columns(&self) -> &[Column] {
        &self.columns
    }

    /// Total number of samples.
    pub fn sample_count(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0) as usize
    }

    /// The sample range of row-major pixel `p` of the data window.
    pub fn pixel_range(&self, p: usize) -> std::ops::Range<usize> {
        self.offsets[p] as usize..self.offsets[p + 1] as usize
    }

    /// The sample range of the pixel at absolute coordinates `(x, y)`, if inside the data window.
    pub fn pixel_at(&self, x: i64, y: i64) -> Option<std::ops::Range<usize>> {
        if !self.data_window.contains(x, y) {
            return None;
        }
        let p = (y - i64::from(self.data_window.y_min)) as usize * self.width()
            + (x - i64::from(self.data_window.x_min)) as usize;
        Some(self.pixel_range(p))
    }

    /// Header attributes kept from a file (or added by the caller) that strata does not
    /// interpret; the writer stores them unchanged.
    pub fn attributes(&self) -> &[Attribute] {
        &self.attributes
    }

    /// Sets (replacing one of the same name) an attribute the writer will store.
    pub fn set_attribute(&mut self, attribute: Attribute) {
        self.attributes.retain(|a| a.name != attribute.name);
        self.attributes.push(attribute);
    }

    /// The attribute called `name`.
    pub fn attribute(&self, name: &str) -> Option<&Attribute> {
        self.attributes.iter().find(|a| a.name == name)
    }

    /// The largest number of samples in one pixel.
    pub fn max_samples_per_pixel(&self) -> u32 {
        self.offsets
            .windows(2)
            .map(|w| w[1] - w[0])
            .max()
            .unwrap_or(0)
    }
}

/// A flat image: one value per pixel and channel, colour premultiplied by alpha.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatImage {
    pub(crate) data_window: Box2i,
    pub(crate) display_window: Box2i,
    pub(crate) channels: Vec<Channel>,
    pub(crate) columns: Vec<Column>,
    pub(crate) attributes: Vec<Attribute>,
}

impl FlatImage {
    /// A flat image over `data_window` (also its display window): `channels` sorted by name, one
    /// column of `width*height` values (row-major from the top) per channel.
    ///
    /// # Errors
    /// [`ExrError::InvalidImage`] naming the first inconsistency.
    pub fn new(data_window: Box2i, channels: Vec<Channel>, columns: Vec<Column>) -> Result<Self> {
        let pixels = check_window(&data_window)?;
        check_channels(&channels)?;
        check_columns(&channels, &columns, pixels)?;
        Ok(FlatImage {
            data_window,
            display_window: data_window,
            channels,
            columns,
            attributes: Vec::new(),
        })
    }

    /// An RGBA image at the origin from premultiplied `[r, g, b, a]` pixels, row-major from the
    /// top, stored as `sample_type` (`Half` or `Float`).
    ///
    /// # Errors
    /// [`ExrError::InvalidImage`] if `pixels` does not hold `width*height` entries.
    pub fn from_rgba(
        width: u32,
        height: u32,
        pixels: &[[f32; 4]],
        sample_type: SampleType,
    ) -> Result<Self> {
        let window = Box2i::from_origin(0, 0, width, height)?;
        let column = |i: usize| Column::F32(pixels.iter().map(|p| p[i]).collect());
        // Sorted names: A, B, G, R.
        let channels = ["A", "B", "G", "R"]
            .iter()
            .map(|n| Channel::new(*n, sample_type))
            .collect();
        FlatImage::new(
            window,
            channels,
            vec![column(3), column(2), column(1), column(0)],
        )
    }

    /// The rectangle the pixels cover.
    pub fn data_window(&self) -> Box2i {
        self.data_window
    }

    /// The rectangle of the whole picture.
    pub fn display_window(&self) -> Box2i {
        self.display_window
    }

    /// Sets the display window.
    pub fn set_display_window(&mut self, window: Box2i) {
        self.display_window = window;
    }

    /// Width of the data window.
    pub fn width(&self) -> usize {
        self.data_window.width() as usize
    }

    /// Height of the data window.
    pub fn height(&self) -> usize {
        self.data_window.height() as usize
    }

    /// The channels, sorted by name.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The index of the channel called `name`.
    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.name == name)
    }

    /// Column `c`.
    pub fn column(&self, c: usize) -> &Column {
        &self.columns[c]
    }

    /// The value of channel `name` at row-major pixel `p` (integers converted), if both exist.
    pub fn value(&self, name: &str, p: usize) -> Option<f64> {
        self.columns[self.channel_index(name)?].get_f64(p)
    }

    /// Attributes kept from a file that strata does not interpret.
    pub fn attributes(&self) -> &[Attribute] {
        &self.attributes
    }

    /// Sets (replacing one of the same name) an attribute the writer will store.
    pub fn set_attribute(&mut self, attribute: Attribute) {
        self.attributes.retain(|a| a.name != attribute.name);
        self.attributes.push(attribute);
    }

    /// Premultiplied `[R, G, B, A]` per pixel, row-major from the top: a missing colour channel
    /// reads as 0 and a missing `A` as 1 (opaque), integer channels are converted.
    pub fn rgba(&self) -> Vec<[f32; 4]> {
        let pixels = self.width() * self.height();
        let channel = |name: &str, default: f32| -> Vec<f32> {
            match self.channel_index(name).map(|c| &self.columns[c]) {
                Some(Column::F32(v)) => v.clone(),
                Some(Column::U32(v)) => v.iter().map(|&x| x as f32).collect(),
                None => vec![default; pixels],
            }
        };
        let (r, g, b, a) = (
            channel("R", 0.0),
            channel("G", 0.0),
            channel("B", 0.0),
            channel("A", 1.0),
        );
        (0..pixels).map(|p| [r[p], g[p], b[p], a[p]]).collect()
    }
}
