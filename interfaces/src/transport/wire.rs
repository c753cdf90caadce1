//! Byte format of farsight messages on zenoh (and in recordings).
//!
//! A fixed message is `FS\x01M` + postcard. A header-plus-slice message is
//! `FS\x01S` + header length (u32 LE) + postcard header + the slice's raw bytes.
//! The slice is copied as-is rather than through serde so a 6 MB frame costs
//! one memcpy; element types are plain-old-data and every supported target
//! (x86-64, aarch64 Jetson) is little-endian.

use bytemuck::Pod;
use serde::de::DeserializeOwned;
use serde::Serialize;

const MAGIC: [u8; 3] = *b"FS\x01";
const TAG_MESSAGE: u8 = b'M';
const TAG_SLICE: u8 = b'S';

/// A payload that could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    #[error("not a farsight v1 message (starts with {0:02x?})")]
    BadMagic(Vec<u8>),
    #[error("expected a {expected} message, got tag {got:?}")]
    WrongShape { expected: &'static str, got: char },
    #[error("truncated: {what} needs {need} bytes, {have} left")]
    Truncated {
        what: &'static str,
        need: usize,
        have: usize,
    },
    #[error("slice of {len} bytes is not a whole number of {elem}-byte elements")]
    RaggedSlice { len: usize, elem: usize },
    #[error("postcard: {0}")]
    Postcard(#[from] postcard::Error),
}

fn check_prefix(bytes: &[u8], tag: u8, expected: &'static str) -> Result<(), WireError> {
    if bytes.len() < 4 || bytes[..3] != MAGIC {
        return Err(WireError::BadMagic(bytes.iter().take(4).copied().collect()));
    }
    if bytes[3] != tag {
        return Err(WireError::WrongShape {
            expected,
            got: bytes[3] as char,
        });
    }
    Ok(())
}

/// The MCAP message encoding of channels whose messages are these bytes
/// (farsight recordings).
pub const MCAP_MESSAGE_ENCODING: &str = "farsight-wire";

/// Encodes a fixed-size message.
pub fn encode_message<M: Serialize>(msg: &M) -> Result<Vec<u8>, WireError> {
    let mut out = Vec::with_capacity(64);
    out.extend_from_slice(&MAGIC);
    out.push(TAG_MESSAGE);
    Ok(postcard::to_extend(msg, out)?)
}

/// Decodes a fixed-size message.
pub fn decode_message<M: DeserializeOwned>(bytes: &[u8]) -> Result<M, WireError> {
    check_prefix(bytes, TAG_MESSAGE, "fixed-size")?;
    Ok(postcard::from_bytes(&bytes[4..])?)
}

/// Encodes a header plus slice.
pub fn encode_slice<H: Serialize, E: Pod>(header: &H, data: &[E]) -> Result<Vec<u8>, WireError> {
    let head = postcard::to_allocvec(header)?;
    let body: &[u8] = bytemuck::cast_slice(data);
    let mut out = Vec::with_capacity(8 + head.len() + body.len());
    out.extend_from_slice(&MAGIC);
    out.push(TAG_SLICE);
    out.extend_from_slice(&(head.len() as u32).to_le_bytes());
    out.extend_from_slice(&head);
    out.extend_from_slice(body);
    Ok(out)
}

/// Decodes a header plus slice, copying the elements out (they may be unaligned
/// in the received buffer).
pub fn decode_slice<H: DeserializeOwned, E: Pod>(bytes: &[u8]) -> Result<(H, Vec<E>), WireError> {
    let (header, body) = split_slice::<H>(bytes)?;
    let elem = core::mem::size_of::<E>();
    if elem == 0 || body.len() % elem != 0 {
        return Err(WireError::RaggedSlice {
            len: body.len(),
            elem,
        });
    }
    let mut data = vec![E::zeroed(); body.len() / elem];
    bytemuck::cast_slice_mut::<E, u8>(&mut data).copy_from_slice(body);
    Ok((header, data))
}

/// Decodes the header and returns the raw payload bytes without copying them.
pub fn split_slice<H: DeserializeOwned>(bytes: &[u8]) -> Result<(H, &[u8]), WireError> {
    check_prefix(bytes, TAG_SLICE, "header+slice")?;
    let rest = &bytes[4..];
    if rest.len() < 4 {
        return Err(WireError::Truncated {
            what: "header length",
            need: 4,
            have: rest.len(),
        });
    }
    let head_len = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]) as usize;
    let rest = &rest[4..];
    if rest.len() < head_len {
        return Err(WireError::Truncated {
            what: "header",
            need: head_len,
            have: rest.len(),
        });
    }
    let header = postcard::from_bytes(&rest[..head_len])?;
    Ok((header, &rest[head_len..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::*;

    #[test]
    fn slice_round_trip_and_errors() {
        let h = CostmapHeader {
            width: 2,
            height: 1,
            resolution_m: 0.5,
            ..Default::default()
        };
        let cells = [
            CostCell {
                cost_s_per_m: 1.0,
                variance: 0.4,
            },
            CostCell {
                cost_s_per_m: f32::INFINITY,
                variance: 0.0,
            },
        ];
        let bytes = encode_slice(&h, &cells).unwrap();
        let (h2, c2): (CostmapHeader, Vec<CostCell>) = decode_slice(&bytes).unwrap();
        assert_eq!(h2, h);
        assert_eq!(c2, cells);
        // A fixed-message decoder refuses a slice message by name.
        let e = decode_message::<Pose>(&bytes).unwrap_err();
        assert!(e.to_string().contains("fixed-size"), "{e}");
        // One byte short leaves a ragged slice.
        let e = decode_slice::<CostmapHeader, CostCell>(&bytes[..bytes.len() - 1]).unwrap_err();
        assert!(matches!(e, WireError::RaggedSlice { .. }), "{e}");
        assert!(matches!(
            decode_slice::<CostmapHeader, CostCell>(b"garbage").unwrap_err(),
            WireError::BadMagic(_)
        ));
    }

    #[test]
    fn message_round_trip() {
        let cmd = VelocityCommand {
            stamp: Stamp::new(7, 9),
            linear_mps: 0.5,
            angular_radps: -0.25,
            reason: CommandReason::TRACKING,
            ttl_ms: 250,
        };
        let bytes = encode_message(&cmd).unwrap();
        assert_eq!(decode_message::<VelocityCommand>(&bytes).unwrap(), cmd);
        assert!(decode_message::<VelocityCommand>(&bytes[..bytes.len() - 2]).is_err());
    }
}
