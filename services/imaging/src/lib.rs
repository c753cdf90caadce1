//! # farsight-imaging
//!
//! Image helpers shared by the stages and tools, so there is one way to do
//! each: downsample a frame, encode it as PNG or JPEG (bridge, snapshots,
//! `farsight infer`), decode a PNG.
//!
//! ```
//! use farsight_imaging::{downsample, encode_png, decode_png};
//! use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
//!
//! let header = ImageHeader::packed(Stamp::new(1, 0), 0, 4, 2, PixelEncoding::MONO8);
//! let pixels = [0u8, 1, 2, 3, 4, 5, 6, 7];
//! let (small, data) = downsample(&header, &pixels, 2)?;
//! assert_eq!((small.width, small.height, data), (2, 1, vec![0, 2]));
//! let png = encode_png(&header, &pixels)?;
//! let (h, back) = decode_png(&png)?;
//! assert_eq!((h.width, back), (4, pixels.to_vec()));
//! # Ok::<(), farsight_imaging::ImageError>(())
//! ```

use farsight_interfaces::msg::{ImageHeader, ImageLayoutError, PixelEncoding, Stamp};

/// An image that cannot be processed as asked.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error(transparent)]
    Layout(#[from] ImageLayoutError),
    #[error("{op} does not support {encoding} images")]
    Unsupported {
        op: &'static str,
        encoding: PixelEncoding,
    },
    #[error("downsample factor {0}: expected 1 or more")]
    BadFactor(u32),
    #[error("png: {0}")]
    Png(String),
    #[error("jpeg: {0}")]
    Jpeg(String),
    #[error("a {width}x{height} image: larger than the {max_width}x{max_height} allowed (or empty); refused before decoding")]
    TooLarge {
        width: u32,
        height: u32,
        max_width: u32,
        max_height: u32,
    },
}

/// Keeps every `factor`-th pixel in both directions (nearest neighbour: cheap,
/// and class-id images must not be blended). Returns a packed image.
pub fn downsample(
    header: &ImageHeader,
    data: &[u8],
    factor: u32,
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    header.validate(data.len())?;
    if factor == 0 {
        return Err(ImageError::BadFactor(factor));
    }
    let bpp = header
        .encoding
        .bytes_per_pixel()
        .ok_or(ImageError::Unsupported {
            op: "downsample",
            encoding: header.encoding,
        })?;
    if header.encoding == PixelEncoding::YUYV && factor != 1 {
        return Err(ImageError::Unsupported {
            op: "downsample",
            encoding: header.encoding,
        });
    }
    let f = factor as usize;
    let (w, h) = (header.width as usize, header.height as usize);
    let (nw, nh) = (w.div_ceil(f), h.div_ceil(f));
    let stride = header.stride_bytes as usize;
    let mut out = Vec::with_capacity(nw * nh * bpp);
    for y in (0..h).step_by(f) {
        let row = &data[y * stride..y * stride + w * bpp];
        if f == 1 {
            out.extend_from_slice(row);
        } else {
            for px in row.chunks_exact(bpp).step_by(f) {
                out.extend_from_slice(px);
            }
        }
    }
    let out_header = ImageHeader::packed(
        header.stamp,
        header.camera_id,
        nw as u32,
        nh as u32,
        header.encoding,
    );
    Ok((out_header, out))
}

/// Packed RGB8 (or MONO8) rows of an image, converting BGR8/RGBA8.
fn packed_rgb_or_gray(
    header: &ImageHeader,
    data: &[u8],
    op: &'static str,
) -> Result<(Vec<u8>, bool), ImageError> {
    header.validate(data.len())?;
    let (w, h, stride) = (
        header.width as usize,
        header.height as usize,
        header.stride_bytes as usize,
    );
    let rows = (0..h).map(|y| &data[y * stride..]);
    let mut out = Vec::with_capacity(w * h * 3);
    match header.encoding {
        PixelEncoding::RGB8 => rows.for_each(|r| out.extend_from_slice(&r[..w * 3])),
        PixelEncoding::BGR8 => rows.for_each(|r| {
            for p in r[..w * 3].chunks_exact(3) {
                out.extend_from_slice(&[p[2], p[1], p[0]]);
            }
        }),
        PixelEncoding::RGBA8 => rows.for_each(|r| {
            for p in r[..w * 4].chunks_exact(4) {
                out.extend_from_slice(&p[..3]);
            }
        }),
        PixelEncoding::MONO8 => {
            rows.for_each(|r| out.extend_from_slice(&r[..w]));
            return Ok((out, true));
        }
        encoding => return Err(ImageError::Unsupported { op, encoding }),
    }
    Ok((out, false))
}

/// Packed RGB8 pixels of an RGB8, BGR8, RGBA8 or MONO8 image (what
/// overlays and viewers draw on).
pub fn to_rgb8(header: &ImageHeader, data: &[u8]) -> Result<Vec<u8>, ImageError> {
    let (packed, gray) = packed_rgb_or_gray(header, data, "rgb8 conversion")?;
    Ok(if gray {
        packed.iter().flat_map(|&g| [g, g, g]).collect()
    } else {
        packed
    })
}

/// Encodes RGB8/BGR8/RGBA8/MONO8/MONO16 as PNG (MONO16 keeps 16 bits; f32
/// heatmaps should be scaled to MONO16 first).
pub fn encode_png(header: &ImageHeader, data: &[u8]) -> Result<Vec<u8>, ImageError> {
    let (bytes, color, depth) = if header.encoding == PixelEncoding::MONO16 {
        header.validate(data.len())?;
        let (w, h, stride) = (
            header.width as usize,
            header.height as usize,
            header.stride_bytes as usize,
        );
        let mut be = Vec::with_capacity(w * h * 2);
        for y in 0..h {
            for px in data[y * stride..y * stride + w * 2].chunks_exact(2) {
                // Our MONO16 is little-endian; PNG stores big-endian.
                be.extend_from_slice(&[px[1], px[0]]);
            }
        }
        (be, png::ColorType::Grayscale, png::BitDepth::Sixteen)
    } else {
        let (packed, gray) = packed_rgb_or_gray(header, data, "png encoding")?;
        let color = if gray {
            png::ColorType::Grayscale
        } else {
            png::ColorType::Rgb
        };
        (packed, color, png::BitDepth::Eight)
    };
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, header.width, header.height);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.set_compression(png::Compression::Fast);
        let mut w = enc
            .write_header()
            .map_err(|e| ImageError::Png(e.to_string()))?;
        w.write_image_data(&bytes)
            .map_err(|e| ImageError::Png(e.to_string()))?;
    }
    Ok(out)
}

/// Encodes RGB8/BGR8/RGBA8/MONO8 as JPEG with `quality` 1..=100.
pub fn encode_jpeg(header: &ImageHeader, data: &[u8], quality: u8) -> Result<Vec<u8>, ImageError> {
    let (packed, gray) = packed_rgb_or_gray(header, data, "jpeg encoding")?;
    let (w, h) = (
        u16::try_from(header.width)
            .map_err(|_| ImageError::Jpeg(format!("width {} exceeds 65535", header.width)))?,
        u16::try_from(header.height)
            .map_err(|_| ImageError::Jpeg(format!("height {} exceeds 65535", header.height)))?,
    );
    let mut out = Vec::new();
    let enc = jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100));
    let color = if gray {
        jpeg_encoder::ColorType::Luma
    } else {
        jpeg_encoder::ColorType::Rgb
    };
    enc.encode(&packed, w, h, color)
        .map_err(|e| ImageError::Jpeg(e.to_string()))?;
    Ok(out)
}

/// The largest image a decoder allocates for: the size in a file's header
/// is checked against it *before* any pixel buffer exists, so a small file
/// that declares a huge image (a decompression bomb) is refused, not
/// allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageLimits {
    pub max_width: u32,
    pub max_height: u32,
}

impl ImageLimits {
    /// What [`decode_png`], [`decode_jpeg`] and [`decode_image`] allow:
    /// 8192 x 8192 (268 MB as RGBA).
    pub const DEFAULT: Self = Self {
        max_width: 8192,
        max_height: 8192,
    };

    fn check(&self, width: u32, height: u32) -> Result<(), ImageError> {
        if width == 0 || height == 0 || width > self.max_width || height > self.max_height {
            return Err(ImageError::TooLarge {
                width,
                height,
                max_width: self.max_width,
                max_height: self.max_height,
            });
        }
        Ok(())
    }
}

/// Decodes a PNG into a packed image (RGB8, RGBA8, MONO8 or little-endian MONO16).
/// A truncated or corrupt file is an error, never a panic; so is one larger
/// than [`ImageLimits::DEFAULT`].
pub fn decode_png(bytes: &[u8]) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    decode_png_within(bytes, ImageLimits::DEFAULT)
}

/// [`decode_png`] with the size checked against `limits` before decoding.
pub fn decode_png_within(
    bytes: &[u8],
    limits: ImageLimits,
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| ImageError::Png(e.to_string()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    limits.check(w, h)?;
    // png 0.18.1 panics expanding a palette that is not a whole number of
    // RGB entries (found by fuzzing); the PNG spec requires one.
    if let Some(p) = reader
        .info()
        .palette
        .as_deref()
        .filter(|p| p.len() % 3 != 0)
    {
        return Err(ImageError::Png(format!(
            "palette of {} bytes: not a whole number of RGB entries",
            p.len()
        )));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| ImageError::Png("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| ImageError::Png(e.to_string()))?;
    buf.truncate(info.buffer_size());
    let encoding = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => PixelEncoding::RGB8,
        (png::ColorType::Rgba, png::BitDepth::Eight) => PixelEncoding::RGBA8,
        (png::ColorType::Grayscale, png::BitDepth::Eight) => PixelEncoding::MONO8,
        (png::ColorType::Grayscale, png::BitDepth::Sixteen) => {
            for px in buf.chunks_exact_mut(2) {
                px.swap(0, 1);
            }
            PixelEncoding::MONO16
        }
        (c, d) => {
            return Err(ImageError::Png(format!(
                "unsupported PNG layout {c:?} {d:?}"
            )))
        }
    };
    let header = ImageHeader::packed(Stamp::default(), 0, info.width, info.height, encoding);
    header.validate(buf.len())?;
    Ok((header, buf))
}

/// Decodes a JPEG (a file, or one MJPEG frame from a camera) into packed RGB8.
/// A truncated stream (no end-of-image marker) or a corrupt header is an
/// error, never a panic; so is one larger than [`ImageLimits::DEFAULT`].
/// (Bit errors inside the entropy-coded data cannot be told from image
/// content: JPEG carries no checksum, and the decoder fills what it cannot
/// read.)
pub fn decode_jpeg(bytes: &[u8]) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    decode_jpeg_within(bytes, ImageLimits::DEFAULT)
}

/// [`decode_jpeg`] with the size checked against `limits` before decoding.
pub fn decode_jpeg_within(
    bytes: &[u8],
    limits: ImageLimits,
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    use zune_jpeg::zune_core::{colorspace::ColorSpace, options::DecoderOptions};
    // zune-jpeg decodes a cut-off stream "successfully", grey-filling the
    // rest: a complete stream ends with EOI (cameras may pad with zeros).
    let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    if end < 4 || bytes[end - 2..end] != [0xff, 0xd9] {
        return Err(ImageError::Jpeg(format!(
            "truncated: no end-of-image marker in {} bytes",
            bytes.len()
        )));
    }
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::RGB);
    // zune-jpeg 0.4 panics on some corrupt headers (sampling factors it
    // cannot handle: an unwrap in mcu.rs, asserts in worker.rs and the
    // upsampler; found by fuzzing). A corrupt file is an error, not a
    // crash of the stage that reads it.
    let (info, mut data) = std::panic::catch_unwind(|| {
        let mut decoder = zune_jpeg::JpegDecoder::new_with_options(bytes, options);
        decoder
            .decode_headers()
            .map_err(|e| ImageError::Jpeg(format!("{e:?}")))?;
        let info = decoder
            .info()
            .ok_or_else(|| ImageError::Jpeg("no image header".into()))?;
        limits.check(u32::from(info.width), u32::from(info.height))?;
        let data = decoder
            .decode()
            .map_err(|e| ImageError::Jpeg(format!("{e:?}")))?;
        Ok((info, data))
    })
    .unwrap_or_else(|_| {
        Err(ImageError::Jpeg(
            "corrupt header (the decoder panicked)".into(),
        ))
    })?;
    // A greyscale JPEG comes out with one channel whatever colour space
    // was asked for: spread it to RGB.
    if data.len() == usize::from(info.width) * usize::from(info.height) {
        data = data.iter().flat_map(|&v| [v, v, v]).collect();
    }
    let header = ImageHeader::packed(
        Stamp::default(),
        0,
        info.width as u32,
        info.height as u32,
        PixelEncoding::RGB8,
    );
    header.validate(data.len())?;
    Ok((header, data))
}

/// A frame as it travels (its header and pixels, which may be a JPEG or
/// PNG) -> the header and raw pixels, keeping the frame's stamp.
pub fn decode_frame(
    header: ImageHeader,
    pixels: &[u8],
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    if header.encoding.is_compressed() {
        let (mut h, p) = decode_image(pixels)?;
        h.stamp = header.stamp;
        Ok((h, p))
    } else {
        header.validate(pixels.len())?;
        Ok((header, pixels.to_vec()))
    }
}

/// Decodes a PNG or JPEG file, told apart by its first bytes, within
/// [`ImageLimits::DEFAULT`].
pub fn decode_image(bytes: &[u8]) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    decode_image_within(bytes, ImageLimits::DEFAULT)
}

/// [`decode_image`] with the size checked against `limits` before decoding.
pub fn decode_image_within(
    bytes: &[u8],
    limits: ImageLimits,
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    if bytes.starts_with(&[0xff, 0xd8]) {
        decode_jpeg_within(bytes, limits)
    } else if bytes.starts_with(b"\x89PNG") {
        decode_png_within(bytes, limits)
    } else {
        Err(ImageError::Png(format!(
            "neither PNG nor JPEG: {} bytes starting {:02x?}",
            bytes.len(),
            &bytes[..bytes.len().min(4)]
        )))
    }
}

/// Converts YUYV (YUV 4:2:2, as V4L2 cameras deliver it) to packed RGB8 with
/// the BT.601 limited-range matrix webcams use.
pub fn yuyv_to_rgb(
    header: &ImageHeader,
    data: &[u8],
) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    header.validate(data.len())?;
    if header.encoding != PixelEncoding::YUYV {
        return Err(ImageError::Unsupported {
            op: "yuyv conversion",
            encoding: header.encoding,
        });
    }
    let (w, h, stride) = (
        header.width as usize,
        header.height as usize,
        header.stride_bytes as usize,
    );
    let mut out = Vec::with_capacity(w * h * 3);
    let px = |y: u8, u: i32, v: i32| {
        let c = (y as i32 - 16).max(0) * 298;
        let clamp = |x: i32| ((x + 128) >> 8).clamp(0, 255) as u8;
        [
            clamp(c + 409 * v),
            clamp(c - 100 * u - 208 * v),
            clamp(c + 516 * u),
        ]
    };
    for row in 0..h {
        let line = &data[row * stride..row * stride + w * 2];
        for (i, q) in line.chunks_exact(4).enumerate() {
            let (u, v) = (q[1] as i32 - 128, q[3] as i32 - 128);
            out.extend_from_slice(&px(q[0], u, v));
            if 2 * i + 1 < w {
                out.extend_from_slice(&px(q[2], u, v));
            }
        }
        if w % 2 == 1 {
            // An odd width ends with half a macropixel: Y then U.
            let q = &line[w * 2 - 2..];
            out.extend_from_slice(&px(q[0], q[1] as i32 - 128, 0));
        }
    }
    let out_header = ImageHeader::packed(
        header.stamp,
        header.camera_id,
        header.width,
        header.height,
        PixelEncoding::RGB8,
    );
    Ok((out_header, out))
}

/// A distinct colour for class `id` (class maps in overlays and snapshots).
pub fn class_color(id: u8) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 8] = [
        [60, 60, 60],
        [46, 204, 64],
        [255, 65, 54],
        [0, 116, 217],
        [255, 220, 0],
        [177, 13, 201],
        [57, 204, 204],
        [255, 133, 27],
    ];
    let base = PALETTE[id as usize % PALETTE.len()];
    // Past the palette, vary brightness so neighbouring ids stay distinguishable.
    let k = 1.0 - 0.25 * ((id as usize / PALETTE.len()) % 3) as f32;
    base.map(|c| (c as f32 * k) as u8)
}

/// Blends per-pixel colours over a packed RGB8 frame. `colors` is a
/// `cw` x `ch` image covering the whole frame (e.g. a model output); each frame
/// pixel takes its nearest entry. `None` leaves the pixel as it is.
pub fn overlay(
    frame: &[u8],
    fw: usize,
    fh: usize,
    cw: usize,
    ch: usize,
    alpha: f32,
    color_at: impl Fn(usize) -> Option<[u8; 3]>,
) -> Vec<u8> {
    let mut out = frame.to_vec();
    for y in 0..fh {
        let cy = (y * ch / fh.max(1)).min(ch.saturating_sub(1));
        for x in 0..fw {
            let cx = (x * cw / fw.max(1)).min(cw.saturating_sub(1));
            if let Some(c) = color_at(cy * cw + cx) {
                let px = &mut out[(y * fw + x) * 3..(y * fw + x) * 3 + 3];
                for k in 0..3 {
                    px[k] = (px[k] as f32 * (1.0 - alpha) + c[k] as f32 * alpha) as u8;
                }
            }
        }
    }
    out
}

/// Scales values in [0, 1] to a 16-bit grey image (heatmaps as PNG).
pub fn unit_to_mono16(values: &[f32]) -> Vec<u8> {
    values
        .iter()
        .flat_map(|v| ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_le_bytes())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Found by fuzzing (tools/fuzz): a JPEG whose SOF declares sampling
    /// factors the decoder cannot handle made zune-jpeg 0.4 panic.
    #[test]
    fn jpeg_with_bogus_sampling_factors_is_an_error_not_a_panic() {
        let (h, d) = rgb(8, 8);
        let good = encode_jpeg(&h, &d, 85).unwrap();
        let sof = good.windows(2).position(|w| w == [0xff, 0xc0]).unwrap();
        // Each component's sampling byte is at sof + 11 + 3 * k.
        for (k, factor) in [(2, 0x24), (1, 0x81), (1, 0x18), (0, 0x88), (2, 0x41)] {
            let mut bad = good.clone();
            bad[sof + 11 + 3 * k] = factor;
            let r = std::panic::catch_unwind(|| decode_jpeg(&bad));
            assert!(r.is_ok(), "component {k} sampling {factor:#x}: panicked");
            if let Ok((h, px)) = r.unwrap() {
                h.validate(px.len()).unwrap();
            }
        }
    }

    /// Found by fuzzing (tools/fuzz): a palette PNG whose PLTE chunk is 5
    /// bytes long (CRCs right) made png 0.18.1 panic while expanding it.
    #[test]
    fn png_with_a_ragged_palette_is_an_error_not_a_panic() {
        #[rustfmt::skip]
        let bad: [u8; 103] = [
            0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
            0x00, 0x00, 0x00, 0x06, 0x00, 0x00, 0x00, 0x03, 0x08, 0x03, 0x00, 0x00, 0x00, 0x87, 0xdf, 0x8e,
            0xc9, 0x00, 0x00, 0x00, 0x05, 0x50, 0x4c, 0x54, 0x45, 0x00, 0x00, 0x00, 0xff, 0x00, 0xf1, 0x42,
            0x29, 0x73, 0x00, 0x00, 0x00, 0x1d, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x61, 0x60, 0x64,
            0x64, 0xfc, 0xcb, 0xc8, 0xc4, 0xcc, 0xc0, 0xf8, 0x8f, 0x99, 0x81, 0x99, 0x91, 0xe1, 0x1f, 0xf3,
            0x7f, 0x06, 0x00, 0x20, 0xed, 0x04, 0x11, 0x74, 0xc5, 0x71, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x49,
            0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
        ];
        let r = std::panic::catch_unwind(|| decode_png(&bad));
        let e = r.expect("no panic").unwrap_err();
        assert!(e.to_string().contains("palette of 5 bytes"), "{e}");
    }

    /// A greyscale JPEG (what `encode_jpeg` writes for MONO8) decodes to RGB.
    #[test]
    fn greyscale_jpeg_decodes_to_rgb() {
        let h = ImageHeader::packed(Stamp::default(), 0, 16, 8, PixelEncoding::MONO8);
        let grey: Vec<u8> = (0..16 * 8).map(|i| (i * 2) as u8).collect();
        let (out, px) = decode_jpeg(&encode_jpeg(&h, &grey, 95).unwrap()).unwrap();
        assert_eq!(
            (out.width, out.height, out.encoding),
            (16, 8, PixelEncoding::RGB8)
        );
        assert_eq!(px.len(), 16 * 8 * 3);
        for (p, g) in px.chunks_exact(3).zip(&grey) {
            assert!(
                p[0] == p[1] && p[1] == p[2] && p[0].abs_diff(*g) <= 8,
                "{p:?} vs {g}"
            );
        }
    }

    fn rgb(w: u32, h: u32) -> (ImageHeader, Vec<u8>) {
        let header = ImageHeader::packed(Stamp::new(3, 4), 1, w, h, PixelEncoding::RGB8);
        let data = (0..w * h * 3).map(|i| (i % 256) as u8).collect();
        (header, data)
    }

    #[test]
    fn downsample_keeps_stamp_and_picks_pixels() {
        let (h, d) = rgb(5, 3);
        let (s, out) = downsample(&h, &d, 2).unwrap();
        assert_eq!((s.width, s.height, s.stamp), (3, 2, h.stamp));
        // Row 0 pixels 0, 2, 4 and row 2 pixels 0, 2, 4.
        assert_eq!(&out[..3], &d[0..3]);
        assert_eq!(&out[3..6], &d[6..9]);
        assert_eq!(&out[9..12], &d[30..33]);
        assert!(matches!(
            downsample(&h, &d, 0),
            Err(ImageError::BadFactor(0))
        ));
        assert!(matches!(
            downsample(&h, &d[1..], 2),
            Err(ImageError::Layout(_))
        ));
    }

    #[test]
    fn png_round_trips_rgb_and_mono16() {
        let (h, d) = rgb(7, 5);
        let (h2, d2) = decode_png(&encode_png(&h, &d).unwrap()).unwrap();
        assert_eq!(
            (h2.width, h2.height, h2.encoding),
            (7, 5, PixelEncoding::RGB8)
        );
        assert_eq!(d2, d);
        let m = ImageHeader::packed(Stamp::default(), 0, 2, 1, PixelEncoding::MONO16);
        let md = [0x34, 0x12, 0xff, 0xee];
        let (_, back) = decode_png(&encode_png(&m, &md).unwrap()).unwrap();
        assert_eq!(back, md);
    }

    #[test]
    fn overlay_blends_the_nearest_entry() {
        // 4x2 grey frame, 2x1 colour map: left half red, right half untouched.
        let frame = vec![100u8; 4 * 2 * 3];
        let out = overlay(&frame, 4, 2, 2, 1, 0.5, |i| (i == 0).then_some([200, 0, 0]));
        assert_eq!(&out[..3], &[150, 50, 50]);
        assert_eq!(&out[3 * 3..3 * 3 + 3], &[100, 100, 100]);
        assert_eq!(&out[(4 + 1) * 3..(4 + 1) * 3 + 3], &[150, 50, 50]);
        assert_ne!(class_color(1), class_color(9));
        assert_eq!(
            unit_to_mono16(&[0.0, 1.0, 2.0]),
            vec![0, 0, 255, 255, 255, 255]
        );
    }

    #[test]
    fn jpeg_round_trip_and_truncation() {
        let h = ImageHeader::packed(Stamp::default(), 0, 32, 16, PixelEncoding::RGB8);
        let d: Vec<u8> = (0..32 * 16).flat_map(|_| [200u8, 100, 50]).collect();
        let j = encode_jpeg(&h, &d, 95).unwrap();
        let (h2, d2) = decode_image(&j).unwrap();
        assert_eq!(
            (h2.width, h2.height, h2.encoding),
            (32, 16, PixelEncoding::RGB8)
        );
        // A flat colour survives JPEG within a few levels.
        assert!(d2
            .chunks(3)
            .all(|p| p[0].abs_diff(200) < 6 && p[1].abs_diff(100) < 6 && p[2].abs_diff(50) < 6));
        assert!(decode_jpeg(&j[..20]).is_err());
        // Cut anywhere, it is refused (zune-jpeg alone grey-fills the rest);
        // zero padding after the end marker, as cameras send, is fine.
        for cut in [j.len() / 4, j.len() / 2, j.len() - 2, j.len() - 1] {
            let e = decode_jpeg(&j[..cut]).unwrap_err().to_string();
            assert!(e.contains("truncated"), "cut at {cut}: {e}");
        }
        let mut padded = j.clone();
        padded.extend_from_slice(&[0; 16]);
        assert!(decode_jpeg(&padded).is_ok());
        // Larger than allowed: refused from the header.
        let small = ImageLimits {
            max_width: 16,
            max_height: 16,
        };
        let e = decode_jpeg_within(&j, small).unwrap_err().to_string();
        assert!(e.contains("32x16") && e.contains("16x16"), "{e}");
    }

    /// A PNG of 1x1 whose header is patched to declare 100000 x 100000 RGB
    /// pixels (CRC fixed up): 30 GB if believed.
    fn png_bomb() -> Vec<u8> {
        let h = ImageHeader::packed(Stamp::default(), 0, 1, 1, PixelEncoding::RGB8);
        let mut png = encode_png(&h, &[1, 2, 3]).unwrap();
        // Signature (8), IHDR length (4) and type (4), then width, height.
        png[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        png[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        png
    }

    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 == 1 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    #[test]
    fn a_png_declaring_a_huge_image_is_refused_before_any_allocation() {
        let bomb = png_bomb();
        assert!(bomb.len() < 200, "{} bytes", bomb.len());
        let e = decode_png(&bomb).unwrap_err().to_string();
        assert!(
            e.contains("100000x100000") && e.contains("8192x8192"),
            "{e}"
        );
        assert!(decode_image(&bomb).is_err());
        // Within a camera's own size, a bigger valid PNG is refused too.
        let h = ImageHeader::packed(Stamp::default(), 0, 64, 48, PixelEncoding::MONO8);
        let png = encode_png(&h, &[7u8; 64 * 48]).unwrap();
        let camera = ImageLimits {
            max_width: 32,
            max_height: 48,
        };
        assert!(decode_png_within(&png, camera).is_err());
        assert!(decode_png_within(&png, ImageLimits::DEFAULT).is_ok());
        // Cut short: an error, not a partial image.
        assert!(decode_png(&png[..png.len() / 2]).is_err());
    }

    #[test]
    fn yuyv_converts_known_colours() {
        // Two macropixels of a captured buffer: white/black, then pure-ish red.
        // (Y=235,U=128,V=128) white; (Y=16) black; red in BT.601: Y=81 U=90 V=240.
        let h = ImageHeader::packed(Stamp::default(), 0, 4, 1, PixelEncoding::YUYV);
        let buf = [235, 128, 16, 128, 81, 90, 81, 240];
        let (rh, rgb) = yuyv_to_rgb(&h, &buf).unwrap();
        assert_eq!(rh.encoding, PixelEncoding::RGB8);
        assert_eq!(&rgb[..6], &[255, 255, 255, 0, 0, 0]);
        assert!(
            rgb[6] > 240 && rgb[7] < 15 && rgb[8] < 15,
            "{:?}",
            &rgb[6..9]
        );
        assert!(yuyv_to_rgb(&h, &buf[..6]).is_err());
    }

    #[test]
    fn truncated_png_is_an_error() {
        let (h, d) = rgb(16, 16);
        let png = encode_png(&h, &d).unwrap();
        assert!(decode_png(&png[..png.len() / 2]).is_err());
        assert!(decode_png(b"not a png").is_err());
    }

    #[test]
    fn jpeg_is_smaller_and_starts_with_soi() {
        let (h, d) = rgb(64, 48);
        let j = encode_jpeg(&h, &d, 80).unwrap();
        assert_eq!(&j[..2], &[0xff, 0xd8]);
        let f = ImageHeader::packed(Stamp::default(), 0, 2, 2, PixelEncoding::F32);
        assert!(matches!(
            encode_jpeg(&f, &[0; 16], 80),
            Err(ImageError::Unsupported { .. })
        ));
    }
}
