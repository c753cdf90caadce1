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

/// Decodes a PNG into a packed image (RGB8, RGBA8, MONO8 or little-endian MONO16).
/// A truncated or corrupt file is an error, never a panic.
pub fn decode_png(bytes: &[u8]) -> Result<(ImageHeader, Vec<u8>), ImageError> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| ImageError::Png(e.to_string()))?;
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

#[cfg(test)]
mod tests {
    use super::*;

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
