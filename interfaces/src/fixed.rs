//! Fixed-capacity containers for shared-memory messages.
//!
//! iceoryx2 payloads may not own heap memory, so variable-length fields of small
//! messages (bin scores, path points, names) live in inline arrays with a length.
//! Over zenoh they serialise as ordinary sequences / strings, so readers on a
//! laptop never see the unused capacity.

use core::fmt;
use iceoryx2::prelude::ZeroCopySend;
use serde::de::{self, SeqAccess, Visitor};
use serde::ser::SerializeSeq;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Error of a push into a full [`FixedVec`] or [`FixedStr`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("capacity {capacity} exceeded (tried to store {requested} items)")]
pub struct CapacityError {
    pub capacity: usize,
    pub requested: usize,
}

/// A vector of at most `N` `Copy` items stored inline.
#[derive(Clone, Copy)]
#[repr(C)]
pub struct FixedVec<T: Copy, const N: usize> {
    len: u32,
    items: [T; N],
}

// SAFETY: `FixedVec` is `repr(C)`, holds no pointers and no `Drop` types when `T`
// itself is `ZeroCopySend`.
unsafe impl<T: Copy + ZeroCopySend, const N: usize> ZeroCopySend for FixedVec<T, N> {}

impl<T: Copy + Default, const N: usize> Default for FixedVec<T, N> {
    fn default() -> Self {
        Self {
            len: 0,
            items: [T::default(); N],
        }
    }
}

impl<T: Copy + Default, const N: usize> FixedVec<T, N> {
    pub const CAPACITY: usize = N;

    pub fn new() -> Self {
        Self::default()
    }

    /// Copies `items`; fails if there are more than `N`.
    pub fn from_slice(items: &[T]) -> Result<Self, CapacityError> {
        let mut v = Self::default();
        if items.len() > N {
            return Err(CapacityError {
                capacity: N,
                requested: items.len(),
            });
        }
        v.items[..items.len()].copy_from_slice(items);
        v.len = items.len() as u32;
        Ok(v)
    }

    pub fn push(&mut self, item: T) -> Result<(), CapacityError> {
        let len = self.len();
        if len >= N {
            return Err(CapacityError {
                capacity: N,
                requested: len + 1,
            });
        }
        self.items[len] = item;
        self.len += 1;
        Ok(())
    }
}

impl<T: Copy, const N: usize> FixedVec<T, N> {
    pub fn len(&self) -> usize {
        (self.len as usize).min(N)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn as_slice(&self) -> &[T] {
        &self.items[..self.len()]
    }

    pub fn as_mut_slice(&mut self) -> &mut [T] {
        let len = self.len();
        &mut self.items[..len]
    }
}

impl<T: Copy + PartialEq, const N: usize> PartialEq for FixedVec<T, N> {
    fn eq(&self, other: &Self) -> bool {
        self.as_slice() == other.as_slice()
    }
}

impl<T: Copy + fmt::Debug, const N: usize> fmt::Debug for FixedVec<T, N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.as_slice()).finish()
    }
}

impl<T: Copy + Serialize, const N: usize> Serialize for FixedVec<T, N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.len()))?;
        for item in self.as_slice() {
            seq.serialize_element(item)?;
        }
        seq.end()
    }
}

impl<'de, T: Copy + Default + Deserialize<'de>, const N: usize> Deserialize<'de>
    for FixedVec<T, N>
{
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T, const N: usize>(core::marker::PhantomData<T>);
        impl<'de, T: Copy + Default + Deserialize<'de>, const N: usize> Visitor<'de> for V<T, N> {
            type Value = FixedVec<T, N>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                write!(f, "a sequence of at most {N} items")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut v = FixedVec::default();
                while let Some(item) = seq.next_element()? {
                    v.push(item)
                        .map_err(|e| de::Error::custom(format_args!("{e}")))?;
                }
                Ok(v)
            }
        }
        d.deserialize_seq(V::<T, N>(core::marker::PhantomData))
    }
}

/// A UTF-8 string of at most `N` bytes stored inline.
#[derive(Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct FixedStr<const N: usize> {
    len: u32,
    bytes: [u8; N],
}

// SAFETY: plain bytes and a length, `repr(C)`.
unsafe impl<const N: usize> ZeroCopySend for FixedStr<N> {}

impl<const N: usize> Default for FixedStr<N> {
    fn default() -> Self {
        Self {
            len: 0,
            bytes: [0; N],
        }
    }
}

impl<const N: usize> FixedStr<N> {
    /// Copies `s`; fails if it is longer than `N` bytes.
    pub fn new(s: &str) -> Result<Self, CapacityError> {
        if s.len() > N {
            return Err(CapacityError {
                capacity: N,
                requested: s.len(),
            });
        }
        let mut out = Self::default();
        out.bytes[..s.len()].copy_from_slice(s.as_bytes());
        out.len = s.len() as u32;
        Ok(out)
    }

    /// Copies `s`, cutting it at a character boundary if it is too long. For
    /// human-readable fields (health reasons) where losing the tail is fine.
    pub fn truncated(s: &str) -> Self {
        let mut end = s.len().min(N);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        Self::new(&s[..end]).unwrap_or_default()
    }

    pub fn as_str(&self) -> &str {
        let len = (self.len as usize).min(N);
        // A peer could write any bytes into shared memory; never trust them to be UTF-8.
        match core::str::from_utf8(&self.bytes[..len]) {
            Ok(s) => s,
            Err(e) => core::str::from_utf8(&self.bytes[..e.valid_up_to()]).unwrap_or(""),
        }
    }
}

impl<const N: usize> fmt::Debug for FixedStr<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl<const N: usize> fmt::Display for FixedStr<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl<const N: usize> Serialize for FixedStr<N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de, const N: usize> Deserialize<'de> for FixedStr<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        FixedStr::new(&s).map_err(de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_vec_refuses_overflow_and_round_trips_postcard() {
        let mut v = FixedVec::<f32, 3>::from_slice(&[1.0, 2.0]).unwrap();
        v.push(3.0).unwrap();
        assert_eq!(
            v.push(4.0),
            Err(CapacityError {
                capacity: 3,
                requested: 4
            })
        );
        let bytes = postcard::to_allocvec(&v).unwrap();
        // length prefix + 3 floats, none of the inline capacity.
        assert_eq!(bytes.len(), 1 + 3 * 4);
        let back: FixedVec<f32, 3> = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back.as_slice(), &[1.0, 2.0, 3.0]);
        let too_long = postcard::to_allocvec(&vec![1.0f32, 2.0, 3.0, 4.0]).unwrap();
        assert!(postcard::from_bytes::<FixedVec<f32, 3>>(&too_long).is_err());
    }

    #[test]
    fn fixed_str_truncates_on_char_boundary_and_survives_garbage() {
        let s = FixedStr::<4>::truncated("aé€");
        assert_eq!(s.as_str(), "aé");
        assert!(FixedStr::<2>::new("abc").is_err());
        let mut garbage = FixedStr::<4>::new("ab").unwrap();
        garbage.bytes[1] = 0xff;
        assert_eq!(garbage.as_str(), "a");
        garbage.len = 99;
        assert_eq!(garbage.as_str(), "a");
    }
}
