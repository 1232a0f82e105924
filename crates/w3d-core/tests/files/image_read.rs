//! `Image::read` / `Image::decode`: PNG (8/16 bit, palette, 1-bit grey), JPEG (EXIF
//! orientation, CMYK) and WebP in, clear errors for oversized headers, truncated files and
//! unknown formats, never a panic.

use std::io::Cursor;
use std::path::Path;

use crate::common::write;
use w3d_core::{Image, ReadLimits};

/// The error message of reading `path`, after checking that it names the file.
fn read_error(path: &Path) -> String {
    let msg = Image::read(path).unwrap_err().to_string();
    assert!(msg.contains(&path.display().to_string()), "error should name {}: {msg}", path.display());
    msg
}

/// An RGB test image: the left half red, the right half blue.
fn halves(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, _| if x < w / 2 { image::Rgb([230, 20, 20]) } else { image::Rgb([20, 20, 230]) })
}

fn jpeg(img: &image::RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95).encode_image(img).unwrap();
    out
}

/// A big-endian EXIF APP1 segment holding one IFD entry: orientation = `value`.
fn exif_app1(value: u16) -> Vec<u8> {
    let mut tiff = b"MM\0\x2a\0\0\0\x08".to_vec();
    tiff.extend_from_slice(&1u16.to_be_bytes()); // one entry
    tiff.extend_from_slice(&0x0112u16.to_be_bytes()); // Orientation
    tiff.extend_from_slice(&3u16.to_be_bytes()); // SHORT
    tiff.extend_from_slice(&1u32.to_be_bytes()); // count
    tiff.extend_from_slice(&value.to_be_bytes());
    tiff.extend_from_slice(&[0, 0]); // value padding
    tiff.extend_from_slice(&0u32.to_be_bytes()); // no next IFD
    let mut payload = b"Exif\0\0".to_vec();
    payload.extend_from_slice(&tiff);
    let mut seg = vec![0xFF, 0xE1];
    seg.extend_from_slice(&((payload.len() + 2) as u16).to_be_bytes());
    seg.extend_from_slice(&payload);
    seg
}

#[test]
fn exif_rotated_jpeg_comes_out_upright() {
    let dir = tempfile::tempdir().unwrap();
    let plain = jpeg(&halves(32, 16));
    assert_eq!(&plain[..2], &[0xFF, 0xD8]);
    let mut rotated = plain[..2].to_vec();
    rotated.extend_from_slice(&exif_app1(6)); // "rotate 90° clockwise to display"
    rotated.extend_from_slice(&plain[2..]);
    let p = write(dir.path(), "rotated.jpg", &rotated);
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (16, 32, 3));
    // Turned clockwise, the red left half is now the top half.
    let top = img.pixel(8, 4);
    let bottom = img.pixel(8, 28);
    assert!(top[0] > 0.7 && top[2] < 0.3, "top should be red: {top:?}");
    assert!(bottom[2] > 0.7 && bottom[0] < 0.3, "bottom should be blue: {bottom:?}");
    // Without the tag, the same pixels read as stored.
    let p = write(dir.path(), "plain.jpg", &plain);
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height()), (32, 16));
}

#[test]
fn format_comes_from_the_bytes_not_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "photo.png", &jpeg(&halves(8, 8)));
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (8, 8, 3));
}

#[test]
fn one_pixel_images_read() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "one.jpg", &jpeg(&image::RgbImage::from_pixel(1, 1, image::Rgb([200, 100, 50]))));
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (1, 1, 3));
    assert!((img.pixel(0, 0)[0] - 200.0 / 255.0).abs() < 0.05);
    let p = dir.path().join("one.png");
    Image::new(1, 1, 4, vec![0.2, 0.4, 0.6, 1.0]).unwrap().write_png(&p).unwrap();
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (1, 1, 4));
}

#[test]
fn sixteen_bit_png_keeps_its_precision() {
    let dir = tempfile::tempdir().unwrap();
    let value = 0x7F01u16; // between two 8-bit levels
    let buf = image::ImageBuffer::<image::Rgb<u16>, _>::from_pixel(3, 2, image::Rgb([value, 0, 65535]));
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb16(buf).write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png).unwrap();
    let p = write(dir.path(), "deep.png", &bytes);
    let img = Image::read(&p).unwrap();
    assert_eq!(img.channels(), 3);
    assert!((img.pixel(2, 1)[0] - value as f32 / 65535.0).abs() < 1e-6);
    assert_eq!(img.pixel(0, 0)[2], 1.0);
}

#[test]
fn webp_reads() {
    let dir = tempfile::tempdir().unwrap();
    let rgba = image::RgbaImage::from_fn(6, 5, |x, y| {
        image::Rgba([x as u8 * 40, y as u8 * 50, 7, if x < 3 { 255 } else { 0 }])
    });
    let mut bytes = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut bytes)
        .encode(rgba.as_raw(), 6, 5, image::ExtendedColorType::Rgba8)
        .unwrap();
    let p = write(dir.path(), "lossless.webp", &bytes);
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (6, 5, 4));
    assert_eq!(img.pixel(1, 4), &[40.0 / 255.0, 200.0 / 255.0, 7.0 / 255.0, 1.0]);
    assert_eq!(img.pixel(4, 0)[3], 0.0);
}

// ---- hand-made PNGs: palette, 1-bit grey, and headers of absurd sizes ----

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    let mut body = kind.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
    out
}

/// A zlib stream holding `data` in one stored (uncompressed) deflate block.
fn zlib_stored(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0x78, 0x01, 0x01];
    let len = data.len() as u16;
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(&(!len).to_le_bytes());
    out.extend_from_slice(data);
    let (mut a, mut b) = (1u32, 0u32);
    for &d in data {
        a = (a + u32::from(d)) % 65521;
        b = (b + a) % 65521;
    }
    out.extend_from_slice(&((b << 16) | a).to_be_bytes());
    out
}

/// A PNG from its IHDR fields, optional PLTE and raw (filtered) scanlines.
fn png(width: u32, height: u32, bit_depth: u8, colour_type: u8, palette: Option<&[u8]>, raw: &[u8]) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[bit_depth, colour_type, 0, 0, 0]);
    out.extend_from_slice(&chunk(b"IHDR", &ihdr));
    if let Some(p) = palette {
        out.extend_from_slice(&chunk(b"PLTE", p));
    }
    out.extend_from_slice(&chunk(b"IDAT", &zlib_stored(raw)));
    out.extend_from_slice(&chunk(b"IEND", &[]));
    out
}

#[test]
fn palette_and_one_bit_grey_pngs_expand() {
    let dir = tempfile::tempdir().unwrap();
    // 2×2, 8-bit indices into a 2-colour palette; each row starts with filter byte 0.
    let bytes = png(2, 2, 8, 3, Some(&[255, 0, 0, 0, 0, 255]), &[0, 0, 1, 0, 1, 0]);
    let p = write(dir.path(), "palette.png", &bytes);
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (2, 2, 3));
    assert_eq!(img.pixel(0, 0), &[1.0, 0.0, 0.0]);
    assert_eq!(img.pixel(1, 0), &[0.0, 0.0, 1.0]);
    // 3×1, 1-bit grey: bits 1 0 1.
    let bytes = png(3, 1, 1, 0, None, &[0, 0b1010_0000]);
    let p = write(dir.path(), "bits.png", &bytes);
    let img = Image::read(&p).unwrap();
    assert_eq!((img.width(), img.height(), img.channels()), (3, 1, 1));
    assert_eq!(img.data(), &[1.0, 0.0, 1.0]);
}

#[test]
fn huge_png_headers_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    for side in [20_000u32, 100_000] {
        // The header claims side × side RGBA pixels; the data is one short row.
        let bytes = png(side, side, 8, 6, None, &[0; 9]);
        let p = write(dir.path(), &format!("huge{side}.png"), &bytes);
        let msg = read_error(&p);
        assert!(msg.contains("16384") && msg.contains(&format!("{side}×{side}")), "{msg}");
    }
    // A tighter budget by pixel count names that limit.
    let bytes = png(4000, 4000, 8, 6, None, &[0; 9]);
    let p = write(dir.path(), "big.png", &bytes);
    let err = Image::read_with_limits(&p, &ReadLimits::default().with_max_pixels(1_000_000)).unwrap_err().to_string();
    assert!(err.contains("1000000") && err.contains("4000×4000"), "{err}");
}

#[test]
fn truncated_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let full = jpeg(&halves(64, 64));
    for cut in [full.len() / 2, full.len() - 2, 40, 3, 0] {
        let p = write(dir.path(), &format!("cut{cut}.jpg"), &full[..cut]);
        let msg = read_error(&p);
        assert!(msg.contains("JPEG") || msg.contains("format"), "{msg}");
    }
    let mut png_bytes = Vec::new();
    image::DynamicImage::ImageRgb8(halves(64, 64))
        .write_to(&mut Cursor::new(&mut png_bytes), image::ImageFormat::Png)
        .unwrap();
    let p = write(dir.path(), "cut.png", &png_bytes[..png_bytes.len() / 2]);
    let msg = read_error(&p);
    assert!(msg.contains("PNG"), "{msg}");
    let p = write(dir.path(), "text.png", b"hello, not an image");
    let msg = read_error(&p);
    assert!(msg.contains("PNG, JPEG or WebP"), "{msg}");
    let p = dir.path().join("missing.jpg");
    assert!(matches!(Image::read(&p), Err(w3d_core::Error::Io { .. })));
}

/// A baseline 8×8 CMYK JPEG with an Adobe marker, crafted by hand (the encoder writes no
/// CMYK): every block has DC difference 0 and no AC terms, so every sample is 128.
fn cmyk_jpeg() -> Vec<u8> {
    let mut out = vec![0xFF, 0xD8];
    // APP14 "Adobe", transform 0 (CMYK, no colour transform).
    out.extend_from_slice(&[0xFF, 0xEE, 0, 14]);
    out.extend_from_slice(b"Adobe");
    out.extend_from_slice(&[0, 100, 0, 0, 0, 0, 0]);
    // One quantisation table of ones.
    out.extend_from_slice(&[0xFF, 0xDB, 0, 67, 0]);
    out.extend_from_slice(&[1; 64]);
    // SOF0: 8 bit, 8×8, 4 components sampled 1×1 with table 0.
    out.extend_from_slice(&[0xFF, 0xC0, 0, 20, 8, 0, 8, 0, 8, 4]);
    for id in 1..=4u8 {
        out.extend_from_slice(&[id, 0x11, 0]);
    }
    // DC and AC tables with one 1-bit code each: DC category 0, AC end-of-block.
    for class in [0x00u8, 0x10] {
        out.extend_from_slice(&[0xFF, 0xC4, 0, 20, class, 1]);
        out.extend_from_slice(&[0; 15]);
        out.push(0);
    }
    // SOS over the 4 components, then 4 blocks × 2 zero bits = one zero byte, then EOI.
    out.extend_from_slice(&[0xFF, 0xDA, 0, 14, 4]);
    for id in 1..=4u8 {
        out.extend_from_slice(&[id, 0x00]);
    }
    out.extend_from_slice(&[0, 63, 0, 0x00, 0xFF, 0xD9]);
    out
}

#[test]
fn cmyk_jpeg_is_converted_or_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "cmyk.jpg", &cmyk_jpeg());
    match Image::read(&p) {
        Ok(img) => {
            // Converted to RGB by the decoder: every pixel the same colour.
            assert_eq!((img.width(), img.height(), img.channels()), (8, 8, 3));
            let first = img.pixel(0, 0).to_vec();
            eprintln!("the CMYK JPEG decoded to RGB {first:?}");
            assert!(img.data().chunks(3).all(|p| p == first.as_slice()), "uniform CMYK gave {:?}", img.data());
        }
        Err(e) => {
            let msg = e.to_string();
            eprintln!("the CMYK JPEG was refused: {msg}");
            assert!(msg.contains(&p.display().to_string()) && msg.contains("JPEG"), "{msg}");
        }
    }
    // Cut inside its scan it is truncated, whatever the colour model.
    let bytes = cmyk_jpeg();
    let p = write(dir.path(), "cmyk_cut.jpg", &bytes[..bytes.len() - 2]);
    read_error(&p);
}

/// The same image written to EXR several times gives the same bytes every time (the encoder
/// compresses the tiles in parallel; they are written in increasing order, not as they
/// finish), and reads back exactly.
#[test]
fn exr_writes_are_byte_for_byte_repeatable() {
    let (w, h) = (512u32, 384u32);
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let data: Vec<f32> = (0..w * h * 4)
        .map(|_| {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect();
    let image = Image::new(w, h, 4, data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let bytes: Vec<Vec<u8>> = (0..6)
        .map(|i| {
            let path = dir.path().join(format!("{i}.exr"));
            image.write_exr(&path).unwrap();
            std::fs::read(&path).unwrap()
        })
        .collect();
    assert!(bytes.iter().all(|b| b == &bytes[0]), "EXR bytes differ between writes of the same image");
    assert_eq!(Image::read_exr(dir.path().join("0.exr")).unwrap(), image);
}
