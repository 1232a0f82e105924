//! Float images (`[H][W][C]`, row-major, origin top-left) and their PNG / EXR IO (feature
//! `io`).

#[cfg(feature = "io")]
use std::io::Write as _;
#[cfg(feature = "io")]
use std::path::Path;

#[cfg(feature = "io")]
use image::ImageEncoder as _;

use crate::error::{Error, Result};

/// A row-major float image with `channels` interleaved values per pixel, origin at the
/// top-left. What the values mean (sRGB colour, encoded normal, mask, depth) is stated by
/// whoever produces the image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    width: u32,
    height: u32,
    channels: u32,
    data: Vec<f32>,
}

impl Image {
    /// An image from its data. Fails if a dimension is zero or `data.len()` is not
    /// `width · height · channels`.
    pub fn new(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Result<Self> {
        if width == 0 || height == 0 || channels == 0 {
            return Err(Error::invalid(
                "image size",
                format!("non-zero width, height and channels, got {width}×{height}×{channels}"),
            ));
        }
        let expected = width as usize * height as usize * channels as usize;
        if data.len() != expected {
            return Err(Error::invalid(
                "image data",
                format!("{expected} values for {width}×{height}×{channels}, got {}", data.len()),
            ));
        }
        Ok(Image { width, height, channels, data })
    }

    /// An image with every value set to `value`. Fails on a zero dimension.
    pub fn filled(width: u32, height: u32, channels: u32, value: f32) -> Result<Self> {
        Self::new(width, height, channels, vec![value; width as usize * height as usize * channels as usize])
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Values per pixel.
    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// All values, `[H][W][C]` row-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// All values, mutable.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Consumes the image, returning its values.
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }

    /// The values of pixel `(x, y)` (column, row). Panics if out of bounds.
    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let i = self.index(x, y);
        &self.data[i..i + self.channels as usize]
    }

    /// The values of pixel `(x, y)`, mutable. Panics if out of bounds.
    pub fn pixel_mut(&mut self, x: u32, y: u32) -> &mut [f32] {
        let i = self.index(x, y);
        let c = self.channels as usize;
        &mut self.data[i..i + c]
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}×{}", self.width, self.height);
        (y as usize * self.width as usize + x as usize) * self.channels as usize
    }

    /// Fails unless the image is `width × height` with `channels` channels; `field` names
    /// the image in the error.
    pub fn expect_shape(&self, field: &str, width: u32, height: u32, channels: u32) -> Result<()> {
        if (self.width, self.height, self.channels) != (width, height, channels) {
            return Err(Error::invalid(
                field,
                format!(
                    "a {width}×{height} image with {channels} channels, got {}×{}×{}",
                    self.width, self.height, self.channels
                ),
            ));
        }
        Ok(())
    }

    /// This 3-channel image with `alpha` (1 channel, same size) appended as a fourth channel:
    /// e.g. a colour view and its mask as RGBA, ready for compositing.
    pub fn with_alpha(&self, alpha: &Image) -> Result<Image> {
        self.expect_shape("colour", self.width, self.height, 3)?;
        alpha.expect_shape("alpha", self.width, self.height, 1)?;
        let data = self.data.chunks_exact(3).zip(&alpha.data).flat_map(|(c, &a)| [c[0], c[1], c[2], a]).collect();
        Image::new(self.width, self.height, 4, data)
    }
}

/// PNG and OpenEXR files (feature `io`).
#[cfg(feature = "io")]
impl Image {
    /// Reads a PNG (8 or 16 bit, grey / grey+alpha / RGB / RGBA) as values in `[0, 1]`
    /// exactly as stored (no colour-space conversion). The channel count is the file's.
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::files::read_input(path)?;
        let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .map_err(|e| Error::format(path, "PNG data", format!("a readable PNG image ({e})")))?;
        from_dynamic(decoded).map_err(|e| e.in_file(path))
    }

    /// Reads a PNG, JPEG or WebP file (the format is recognised from the first bytes, not
    /// the extension) with the default [`ReadLimits`]; see [`Image::decode`].
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        Self::read_with_limits(path, &ReadLimits::default())
    }

    /// Reads a PNG, JPEG or WebP file within `limits`; see [`Image::decode`]. Errors name
    /// the file.
    pub fn read_with_limits(path: impl AsRef<Path>, limits: &ReadLimits) -> Result<Self> {
        let path = path.as_ref();
        let len = crate::files::regular_file(path)?.len();
        // No image format stores fewer than 1/8 byte per pixel on the way in: a file bigger
        // than the whole decoded budget is refused before it is read.
        let max_file = limits.max_pixels.saturating_mul(8).saturating_add(1 << 20);
        if len > max_file {
            return Err(Error::format(
                path,
                "file size",
                format!("at most {max_file} bytes for an image within the decoding limits, got {len}"),
            ));
        }
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::decode(&bytes, limits).map_err(|e| e.in_file(path))
    }

    /// Decodes a PNG, JPEG or WebP file held in memory into values in `[0, 1]`, as stored
    /// (sRGB stays sRGB; no ICC conversion), with the file's channel count: 1 (grey), 2
    /// (grey + alpha), 3 (RGB) or 4 (RGBA). Palette and low-bit-depth PNGs are expanded,
    /// 16-bit PNGs keep their precision, CMYK JPEGs are converted to RGB by the decoder, and
    /// the EXIF orientation (JPEG, WebP, PNG `eXIf`) is applied so the image comes out
    /// upright.
    ///
    /// The size in the header is checked against `limits` before any pixel memory is
    /// allocated; a truncated or corrupt file is an error, never a panic.
    pub fn decode(bytes: &[u8], limits: &ReadLimits) -> Result<Self> {
        use image::ImageDecoder as _;

        let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| Error::invalid("image data", format!("readable bytes ({e})")))?;
        let format = match reader.format() {
            Some(f @ (image::ImageFormat::Png | image::ImageFormat::Jpeg | image::ImageFormat::WebP)) => f,
            Some(other) => {
                return Err(Error::invalid(
                    "image format",
                    format!("a PNG, JPEG or WebP image, got {}", format_name(other)),
                ));
            }
            None => {
                return Err(Error::invalid(
                    "image format",
                    "a PNG, JPEG or WebP image (the first bytes match none of these formats)",
                ));
            }
        };
        let name = format_name(format);
        if format == image::ImageFormat::Jpeg && !jpeg_has_end(bytes) {
            // The JPEG decoder pads a cut-off scan with grey instead of failing.
            return Err(Error::invalid(
                "JPEG data",
                "a complete JPEG file, but it has no end-of-image marker after its last scan (truncated?)",
            ));
        }
        let mut reader = reader;
        // The decoders' own budget (the PNG decoder checks it while reading the header);
        // the dimensions are checked below, by us, so the error can name them.
        let mut decoder_limits = image::Limits::no_limits();
        decoder_limits.max_alloc = Some(limits.max_pixels.saturating_mul(8).saturating_add(1 << 20));
        reader.limits(decoder_limits);
        let mut decoder = reader.into_decoder().map_err(|e| decode_error(name, e, limits))?;
        let (w, h) = decoder.dimensions();
        if w == 0 || h == 0 {
            return Err(Error::invalid("image size", format!("a non-empty {name} image, the header says {w}×{h}")));
        }
        if w > limits.max_side || h > limits.max_side {
            return Err(Error::invalid(
                "image size",
                format!(
                    "at most {m}×{m} pixels (the decoding limit, ReadLimits::max_side), the {name} header says {w}×{h}",
                    m = limits.max_side
                ),
            ));
        }
        let pixels = u64::from(w) * u64::from(h);
        if pixels > limits.max_pixels {
            return Err(Error::invalid(
                "image size",
                format!(
                    "at most {} pixels (the decoding limit, ReadLimits::max_pixels), the {name} header says {w}×{h} = {pixels}",
                    limits.max_pixels
                ),
            ));
        }
        // A corrupt EXIF block is no reason to refuse the pixels: read them unrotated.
        let orientation = decoder.orientation().unwrap_or(image::metadata::Orientation::NoTransforms);
        let mut decoded = image::DynamicImage::from_decoder(decoder).map_err(|e| decode_error(name, e, limits))?;
        decoded.apply_orientation(orientation);
        from_dynamic(decoded)
    }
    /// Reads a PNG and requires `channels` channels (`field` names the image in errors).
    pub fn read_png_channels(path: impl AsRef<Path>, channels: u32) -> Result<Self> {
        let path = path.as_ref();
        let img = Self::read_png(path)?;
        if img.channels != channels {
            return Err(Error::format(path, "PNG channels", format!("{channels} channels, got {}", img.channels)));
        }
        Ok(img)
    }

    /// Encodes an 8-bit PNG (1, 2, 3 or 4 channels) in memory. Values are clamped to
    /// `[0, 1]` and rounded (`v·255 + 0.5`); NaN is an error, not a silent zero.
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let color = match self.channels {
            1 => image::ExtendedColorType::L8,
            2 => image::ExtendedColorType::La8,
            3 => image::ExtendedColorType::Rgb8,
            4 => image::ExtendedColorType::Rgba8,
            c => return Err(Error::invalid("image channels", format!("1 to 4 channels for PNG, got {c}"))),
        };
        if let Some(i) = self.data.iter().position(|v| v.is_nan()) {
            return Err(Error::invalid(format!("image value {i}"), "a number, got NaN"));
        }
        let bytes: Vec<u8> = self.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8).collect();
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&bytes, self.width, self.height, color)
            .map_err(|e| Error::invalid("image", format!("an encodable PNG ({e})")))?;
        Ok(png)
    }

    /// Writes an 8-bit PNG (1, 2, 3 or 4 channels) atomically; see [`Image::encode_png`].
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let png = self.encode_png()?;
        crate::files::write_atomic(path, |w| w.write_all(&png).map_err(|e| Error::io(path, e)))
    }

    /// Reads the first RGBA layer of an OpenEXR file as a 4-channel f32 image (missing
    /// channels read as 0, alpha as 1). The header's data window is checked first
    /// ([`crate::io::check_exr_size`]): a file claiming more than 8192² pixels is refused
    /// before anything of that size is allocated.
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        crate::exr_limits::check_exr_size(path)?;
        let image = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |resolution, _| (resolution.width(), vec![0.0f32; resolution.width() * resolution.height() * 4]),
            |(width, data), pos, (r, g, b, a): (f32, f32, f32, f32)| {
                let i = (pos.y() * *width + pos.x()) * 4;
                data[i..i + 4].copy_from_slice(&[r, g, b, a]);
            },
        )
        .map_err(|e| match e {
            exr::error::Error::Io(io) => Error::io(path, io),
            other => Error::format(path, "EXR data", format!("a readable RGBA OpenEXR image ({other})")),
        })?;
        let size = image.layer_data.size;
        let (_, data) = image.layer_data.channel_data.pixels;
        Image::new(size.width() as u32, size.height() as u32, 4, data).map_err(|e| e.in_file(path))
    }

    /// Writes the image as a 32-bit float RGBA OpenEXR file, atomically; the same image always
    /// gives the same bytes. 1-channel images are written as grey (R = G = B) with alpha 1,
    /// 3-channel images with alpha 1.
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let c = self.channels as usize;
        if !matches!(c, 1 | 3 | 4) {
            return Err(Error::invalid("image channels", format!("1, 3 or 4 channels for EXR, got {c}")));
        }
        let w = self.width as usize;
        let rgba = |x: usize, y: usize| -> (f32, f32, f32, f32) {
            let p = &self.data[(y * w + x) * c..(y * w + x + 1) * c];
            match c {
                1 => (p[0], p[0], p[0], 1.0),
                3 => (p[0], p[1], p[2], 1.0),
                _ => (p[0], p[1], p[2], p[3]),
            }
        };
        let channels = exr::prelude::SpecificChannels::rgba(|exr::math::Vec2(x, y)| rgba(x, y));
        // Blocks in increasing order: the encoder compresses them in parallel, and with an
        // unspecified order it writes each as it finishes, so the same image gave files that
        // differed from run to run (same pixels, other bytes).
        let encoding = exr::prelude::Encoding {
            line_order: exr::prelude::LineOrder::Increasing,
            ..exr::prelude::Encoding::default()
        };
        let image = exr::prelude::Image::from_encoded_channels((w, self.height as usize), encoding, channels);
        crate::files::write_atomic(path, |file| {
            use exr::prelude::WritableImage as _;
            image.write().to_buffered(file).map_err(|e| match e {
                exr::error::Error::Io(io) => Error::io(path, io),
                other => Error::format(path, "EXR encoding", other.to_string()),
            })
        })
    }
}

/// Size limits of [`Image::read`] / [`Image::decode`], checked against the file's header
/// before any pixel memory is allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct ReadLimits {
    /// Largest accepted width or height (default 16384).
    pub max_side: u32,
    /// Largest accepted pixel count (default 2²⁶ ≈ 67 million, about 1 GiB as RGBA `f32`).
    pub max_pixels: u64,
}

impl Default for ReadLimits {
    fn default() -> Self {
        ReadLimits { max_side: 16384, max_pixels: 1 << 26 }
    }
}

impl ReadLimits {
    crate::setters! {
        /// The same limits with another largest side.
        with_max_side(max_side: u32);
        /// The same limits with another largest pixel count.
        with_max_pixels(max_pixels: u64);
    }
}

/// A decoded image as `[0, 1]` floats with its own channel count (8- and 16-bit grey, grey +
/// alpha, RGB, RGBA).
#[cfg(feature = "io")]
fn from_dynamic(decoded: image::DynamicImage) -> Result<Image> {
    let (w, h) = (decoded.width(), decoded.height());
    let channels = u32::from(decoded.color().channel_count());
    let data: Vec<f32> = match decoded {
        image::DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
        image::DynamicImage::ImageLumaA8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
        image::DynamicImage::ImageRgb8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
        image::DynamicImage::ImageRgba8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
        image::DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
        image::DynamicImage::ImageLumaA16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
        image::DynamicImage::ImageRgb16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
        image::DynamicImage::ImageRgba16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
        other => {
            return Err(Error::invalid(
                "image colour type",
                format!("8- or 16-bit grey/RGB(A), got {:?}", other.color()),
            ));
        }
    };
    Image::new(w, h, channels, data)
}

/// Whether a JPEG file has its end-of-image marker (FF D9) after the start of its last scan
/// (FF DA). Inside entropy-coded data every FF byte is followed by 00 or a restart marker, so
/// an FF D9 there is the real end; an EXIF thumbnail's own markers come before the scans.
#[cfg(feature = "io")]
fn jpeg_has_end(bytes: &[u8]) -> bool {
    let Some(last_scan) = bytes.windows(2).rposition(|w| w == [0xFF, 0xDA]) else {
        return false;
    };
    bytes[last_scan..].windows(2).any(|w| w == [0xFF, 0xD9])
}

/// The name of a format in messages.
#[cfg(feature = "io")]
fn format_name(format: image::ImageFormat) -> &'static str {
    match format {
        image::ImageFormat::Png => "PNG",
        image::ImageFormat::Jpeg => "JPEG",
        image::ImageFormat::WebP => "WebP",
        image::ImageFormat::Gif => "GIF",
        image::ImageFormat::Tiff => "TIFF",
        image::ImageFormat::Bmp => "BMP",
        image::ImageFormat::OpenExr => "OpenEXR (use Image::read_exr)",
        image::ImageFormat::Avif => "AVIF",
        _ => "another image format",
    }
}

/// A decoder error as an [`Error::Invalid`] saying what was wrong with the data.
#[cfg(feature = "io")]
fn decode_error(name: &str, e: image::ImageError, limits: &ReadLimits) -> Error {
    match e {
        image::ImageError::Limits(l) => Error::invalid(
            "image size",
            format!(
                "an image within the decoding limits ({m}×{m} pixels, {p} pixels in all): {l}",
                m = limits.max_side,
                p = limits.max_pixels
            ),
        ),
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::invalid(format!("{name} data"), format!("a complete {name} file, but it ends early (truncated?)"))
        }
        other => Error::invalid(format!("{name} data"), format!("a readable {name} image ({other})")),
    }
}

/// sRGB-encoded value in `[0, 1]` → linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// Linear value in `[0, 1]` → sRGB-encoded.
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.0031308 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}
