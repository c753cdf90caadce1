//! Decoding of ROS 2 `sensor_msgs/msg/Image` and `sensor_msgs/msg/CompressedImage`
//! from CDR (the encoding rosbag2 writes into MCAP), so a user can replay a log
//! from their own robot into the graph.
//!
//! CDR: a 4-byte encapsulation header (`00 01` = little-endian), then each
//! field aligned to its own size, counted from the end of that header. Strings
//! and sequences are a u32 length followed by their bytes (strings include a
//! terminating NUL).

use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};

/// A message that is not a usable image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CdrError {
    #[error("CDR message too short: {what} at byte {at} needs {need} bytes, {have} left")]
    Truncated {
        what: &'static str,
        at: usize,
        need: usize,
        have: usize,
    },
    #[error("unsupported CDR encapsulation {0:02x?} (expected little-endian CDR 00 01)")]
    Encapsulation([u8; 2]),
    #[error(
        "image encoding {0:?} is not supported (rgb8, bgr8, rgba8, mono8, mono16, yuv422_yuy2 are)"
    )]
    Encoding(String),
    #[error("image data holds {got} bytes, but height {height} x step {step} needs {need}")]
    Size {
        got: usize,
        need: usize,
        height: u32,
        step: u32,
    },
    #[error("big-endian image data is not supported")]
    BigEndian,
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(msg: &'a [u8]) -> Result<Self, CdrError> {
        if msg.len() < 4 {
            return Err(CdrError::Truncated {
                what: "encapsulation",
                at: 0,
                need: 4,
                have: msg.len(),
            });
        }
        if msg[..2] != [0x00, 0x01] {
            return Err(CdrError::Encapsulation([msg[0], msg[1]]));
        }
        Ok(Self {
            buf: &msg[4..],
            pos: 0,
        })
    }

    fn take(&mut self, what: &'static str, n: usize, align: usize) -> Result<&'a [u8], CdrError> {
        self.pos = self.pos.div_ceil(align) * align;
        let have = self.buf.len().saturating_sub(self.pos);
        if have < n {
            return Err(CdrError::Truncated {
                what,
                at: self.pos + 4,
                need: n,
                have,
            });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        let b = self.take(what, 4, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(what, 1, 1)?[0])
    }

    fn string(&mut self, what: &'static str) -> Result<String, CdrError> {
        let n = self.u32(what)? as usize;
        let b = self.take(what, n, 1)?;
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        Ok(String::from_utf8_lossy(b).into_owned())
    }

    fn bytes(&mut self, what: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(what)? as usize;
        self.take(what, n, 1)
    }

    /// `std_msgs/Header`: the stamp in nanoseconds (frame_id is skipped).
    fn header(&mut self) -> Result<u64, CdrError> {
        let sec = self.u32("header.stamp.sec")? as i32;
        let nanosec = self.u32("header.stamp.nanosec")?;
        self.string("header.frame_id")?;
        Ok((sec.max(0) as u64) * 1_000_000_000 + nanosec as u64)
    }
}

/// A decoded ROS image: farsight header (stamp = the ROS header stamp) and
/// packed pixels (RGB8 for compressed images).
pub type RosImage = (ImageHeader, Vec<u8>);

/// Decodes a CDR `sensor_msgs/msg/Image`.
pub fn decode_image(msg: &[u8]) -> Result<RosImage, CdrError> {
    let mut r = Reader::new(msg)?;
    let stamp_ns = r.header()?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let encoding = r.string("encoding")?;
    let big_endian = r.u8("is_bigendian")?;
    let step = r.u32("step")?;
    let data = r.bytes("data")?;
    let enc = match encoding.as_str() {
        "rgb8" => PixelEncoding::RGB8,
        "bgr8" => PixelEncoding::BGR8,
        "rgba8" => PixelEncoding::RGBA8,
        "mono8" | "8UC1" => PixelEncoding::MONO8,
        "mono16" | "16UC1" => PixelEncoding::MONO16,
        "yuv422_yuy2" | "yuyv" => PixelEncoding::YUYV,
        _ => return Err(CdrError::Encoding(encoding)),
    };
    if big_endian != 0 && enc == PixelEncoding::MONO16 {
        return Err(CdrError::BigEndian);
    }
    let header = ImageHeader {
        stamp: Stamp::new(0, stamp_ns),
        camera_id: 0,
        width,
        height,
        stride_bytes: step,
        encoding: enc,
    };
    let need = height as usize * step as usize;
    if data.len() != need || header.validate(data.len()).is_err() {
        return Err(CdrError::Size {
            got: data.len(),
            need,
            height,
            step,
        });
    }
    Ok((header, data.to_vec()))
}

/// Decodes a CDR `sensor_msgs/msg/CompressedImage` (JPEG or PNG) into RGB8.
pub fn decode_compressed(msg: &[u8]) -> Result<RosImage, anyhow::Error> {
    let mut r = Reader::new(msg)?;
    let stamp_ns = r.header()?;
    let _format = r.string("format")?;
    let data = r.bytes("data")?;
    let (mut h, px) = farsight_imaging::decode_image(data)?;
    h.stamp = Stamp::new(0, stamp_ns);
    Ok((h, px))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2x1 rgb8 Image written out field by field, offsets by hand.
    fn hand_made_image() -> Vec<u8> {
        let mut m = vec![0x00, 0x01, 0x00, 0x00]; // CDR little-endian
        m.extend(7u32.to_le_bytes()); // stamp.sec        @0
        m.extend(500u32.to_le_bytes()); // stamp.nanosec  @4
        m.extend(4u32.to_le_bytes()); // frame_id length  @8 ("cam" + NUL)
        m.extend(b"cam\0"); //                            @12
        m.extend(1u32.to_le_bytes()); // height           @16
        m.extend(2u32.to_le_bytes()); // width            @20
        m.extend(5u32.to_le_bytes()); // encoding length  @24
        m.extend(b"rgb8\0"); //                           @28..33
        m.push(0); // is_bigendian                        @33
        m.extend([0, 0]); // pad to 4                     @34
        m.extend(6u32.to_le_bytes()); // step             @36
        m.extend(6u32.to_le_bytes()); // data length      @40
        m.extend([1, 2, 3, 4, 5, 6]); //                  @44
        m
    }

    #[test]
    fn hand_made_image_decodes() {
        let (h, d) = decode_image(&hand_made_image()).unwrap();
        assert_eq!(
            (h.width, h.height, h.stride_bytes, h.encoding),
            (2, 1, 6, PixelEncoding::RGB8)
        );
        assert_eq!(h.stamp.capture_time_ns, 7_000_000_500);
        assert_eq!(d, vec![1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn truncated_and_inconsistent_messages_are_errors() {
        let m = hand_made_image();
        let e = decode_image(&m[..m.len() - 1]).unwrap_err();
        assert!(matches!(e, CdrError::Truncated { what: "data", .. }), "{e}");
        let mut wrong = m.clone();
        wrong[4 + 36] = 7; // step 7: 1 row x 7 bytes != 6 bytes of data
        assert!(matches!(
            decode_image(&wrong).unwrap_err(),
            CdrError::Size { .. }
        ));
        let mut be = m.clone();
        be[1] = 0x00; // big-endian CDR
        assert!(matches!(
            decode_image(&be).unwrap_err(),
            CdrError::Encapsulation(_)
        ));
        let mut bayer = m.clone();
        bayer[4 + 28..4 + 32].copy_from_slice(b"bgg8");
        assert_eq!(
            decode_image(&bayer).unwrap_err(),
            CdrError::Encoding("bgg8".into())
        );
    }
}
