//! The mutation engine: deterministic from a seed, byte-level for every
//! target and token-level for text (config) targets.

/// splitmix64 to spread a seed, then xorshift64* (small, fast, and the same
/// sequence on every machine).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        let mut z = seed.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        Self(z.max(1))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `0..n` (`n` > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    pub fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }

    pub fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Inputs grow no larger than this (a mutation that would is cut back).
pub const MAX_INPUT: usize = 1 << 17;

/// Values that sit on the edges decoders get wrong, written little-endian.
const INTERESTING: [u64; 12] = [
    0,
    1,
    0x7f,
    0x80,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x7fff_ffff_ffff_ffff,
    u64::MAX,
];

/// What a number in a text input may become.
const NUMBERS: [&str; 16] = [
    "nan",
    "inf",
    "-inf",
    "-1",
    "0",
    "-0.0",
    "1e308",
    "-1e308",
    "1e-320",
    "4294967296",
    "18446744073709551616",
    "99999999999999999999999999",
    "9223372036854775807",
    "-9223372036854775808",
    "\"text\"",
    "[]",
];

/// One random change of `data` (`others` are inputs to splice from).
pub fn mutate_bytes(rng: &mut Rng, data: &mut Vec<u8>, others: &[&[u8]]) {
    let len = data.len();
    match rng.below(11) {
        // Flip a bit.
        0 if len > 0 => {
            let i = rng.below(len);
            data[i] ^= 1 << rng.below(8);
        }
        // A random byte.
        1 if len > 0 => {
            let i = rng.below(len);
            data[i] = rng.next_u64() as u8;
        }
        // An interesting value, 1, 2, 4 or 8 bytes wide.
        2 if len > 0 => {
            let width = *rng.pick(&[1usize, 2, 4, 8]);
            let mut v = *rng.pick(&INTERESTING);
            if rng.chance(4) {
                v = v.wrapping_neg();
            }
            let at = rng.below(len);
            let bytes = v.to_le_bytes();
            let n = width.min(len - at);
            data[at..at + n].copy_from_slice(&bytes[..n]);
        }
        // Add or subtract a little from a byte or a u32.
        3 if len >= 4 => {
            let at = rng.below(len - 3);
            let delta = rng.below(33) as u32;
            let mut w = u32::from_le_bytes(data[at..at + 4].try_into().expect("4 bytes"));
            w = if rng.chance(2) {
                w.wrapping_add(delta)
            } else {
                w.wrapping_sub(delta)
            };
            data[at..at + 4].copy_from_slice(&w.to_le_bytes());
        }
        // Insert random bytes.
        4 => {
            let at = rng.below(len + 1);
            let n = 1 + rng.below(16);
            let fill: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            data.splice(at..at, fill);
        }
        // Delete a range.
        5 if len > 0 => {
            let at = rng.below(len);
            let n = 1 + rng.below((len - at).min(64));
            data.drain(at..at + n);
        }
        // Duplicate a range somewhere else.
        6 if len > 0 => {
            let at = rng.below(len);
            let n = 1 + rng.below((len - at).min(256));
            let copy = data[at..at + n].to_vec();
            let to = rng.below(len + 1);
            data.splice(to..to, copy);
        }
        // Cut the end off.
        7 if len > 0 => data.truncate(rng.below(len)),
        // Splice: this input's head, another's tail.
        8 if !others.is_empty() => {
            let other = *rng.pick(others);
            let head = rng.below(len + 1);
            let tail = rng.below(other.len() + 1);
            data.truncate(head);
            data.extend_from_slice(&other[tail..]);
        }
        // Overwrite a range with a piece of another input.
        9 if !others.is_empty() && len > 0 => {
            let other = *rng.pick(others);
            if !other.is_empty() {
                let from = rng.below(other.len());
                let n = (1 + rng.below(64)).min(other.len() - from);
                let at = rng.below(len);
                let n = n.min(len - at);
                data[at..at + n].copy_from_slice(&other[from..from + n]);
            }
        }
        // Fill a range with one byte (runs of zeros or 0xff).
        _ if len > 0 => {
            let at = rng.below(len);
            let n = 1 + rng.below((len - at).min(32));
            let b = *rng.pick(&[0u8, 0xff, b'0', b' ']);
            data[at..at + n].fill(b);
        }
        _ => data.push(rng.next_u64() as u8),
    }
    data.truncate(MAX_INPUT);
}

/// The spans of number tokens in `text` (digits with an optional sign,
/// point and exponent), by byte range.
fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        if text[i].is_ascii_digit() {
            let mut start = i;
            if start > 0 && (text[start - 1] == b'-' || text[start - 1] == b'+') {
                start -= 1;
            }
            while i < text.len()
                && (text[i].is_ascii_digit() || matches!(text[i], b'.' | b'e' | b'E' | b'_'))
            {
                i += 1;
            }
            out.push((start, i));
        } else {
            i += 1;
        }
    }
    out
}

/// One change of a text input at the level of its tokens: a number becomes
/// an edge value, a quote or bracket goes, a line is dropped, doubled or
/// borrowed from another input.
pub fn mutate_text(rng: &mut Rng, data: &mut Vec<u8>, others: &[&[u8]]) {
    let line_starts = |d: &[u8]| -> Vec<usize> {
        std::iter::once(0)
            .chain(
                d.iter()
                    .enumerate()
                    .filter(|(_, &b)| b == b'\n')
                    .map(|(i, _)| i + 1),
            )
            .filter(|&i| i < d.len())
            .collect()
    };
    let line_at = |d: &[u8], start: usize| -> (usize, usize) {
        let end = d[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(d.len(), |p| start + p + 1);
        (start, end)
    };
    match rng.below(6) {
        // A number becomes an edge value.
        0 | 1 => {
            let spans = numbers(data);
            if spans.is_empty() {
                return mutate_bytes(rng, data, others);
            }
            let (a, b) = *rng.pick(&spans);
            let to = rng.pick(&NUMBERS).as_bytes().to_vec();
            data.splice(a..b, to);
        }
        // A quote, bracket, brace, `=` or comma goes (or is doubled).
        2 => {
            let marks: Vec<usize> = data
                .iter()
                .enumerate()
                .filter(|(_, b)| b"\"'[]{}=,".contains(b))
                .map(|(i, _)| i)
                .collect();
            if marks.is_empty() {
                return mutate_bytes(rng, data, others);
            }
            let i = *rng.pick(&marks);
            if rng.chance(3) {
                let b = data[i];
                data.insert(i, b);
            } else {
                data.remove(i);
            }
        }
        // A line goes, or is doubled.
        3 => {
            let starts = line_starts(data);
            if starts.is_empty() {
                return mutate_bytes(rng, data, others);
            }
            let (a, b) = line_at(data, *rng.pick(&starts));
            if rng.chance(2) {
                data.drain(a..b);
            } else {
                let line = data[a..b].to_vec();
                data.splice(b..b, line);
            }
        }
        // A line of another input goes in.
        4 if !others.is_empty() => {
            let other = *rng.pick(others);
            let starts = line_starts(other);
            if starts.is_empty() {
                return mutate_bytes(rng, data, others);
            }
            let (a, b) = line_at(other, *rng.pick(&starts));
            let mut line = other[a..b].to_vec();
            if !line.ends_with(b"\n") {
                line.push(b'\n');
            }
            let mine = line_starts(data);
            let to = if mine.is_empty() { 0 } else { *rng.pick(&mine) };
            data.splice(to..to, line);
        }
        _ => mutate_bytes(rng, data, others),
    }
    data.truncate(MAX_INPUT);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_makes_the_same_inputs() {
        let seed = b"width = 640\nheight = 480\nname = \"front\"\n".to_vec();
        let run = |s| {
            let mut rng = Rng::new(s);
            let mut d = seed.clone();
            for _ in 0..100 {
                mutate_text(&mut rng, &mut d, &[&seed]);
                mutate_bytes(&mut rng, &mut d, &[&seed]);
            }
            d
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
    }

    #[test]
    fn numbers_are_found_with_their_sign() {
        let t = b"a = -1.5e3\nb = [2, 30]\n";
        let spans: Vec<&[u8]> = numbers(t).iter().map(|&(a, b)| &t[a..b]).collect();
        assert_eq!(spans, [&b"-1.5e3"[..], b"2", b"30"]);
    }

    #[test]
    fn mutations_never_panic_and_stay_bounded() {
        let mut rng = Rng::new(1);
        for start in [&b""[..], b"x", b"\n", b"[a]\nb = 1\n"] {
            for _ in 0..2000 {
                let mut d = start.to_vec();
                for _ in 0..8 {
                    mutate_text(&mut rng, &mut d, &[start, b""]);
                    mutate_bytes(&mut rng, &mut d, &[]);
                }
                assert!(d.len() <= MAX_INPUT);
            }
        }
    }
}
