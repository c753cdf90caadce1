//! Topic selection by glob pattern (the recorder's topics, `farsight foxglove`'s
//! rate rules): `*` matches within one path segment,
//! `**` across segments (`camera/*/image`, `costmap/**`, `**`).

/// Whether `topic` matches `pattern`.
///
/// ```
/// use farsight_interfaces::pattern::matches;
/// assert!(matches("camera/*/image", "camera/front/image"));
/// assert!(!matches("camera/*", "camera/front/image"));
/// assert!(matches("**", "nav/path/planned"));
/// ```
pub fn matches(pattern: &str, topic: &str) -> bool {
    fn go(p: &[u8], t: &[u8]) -> bool {
        match p {
            [] => t.is_empty(),
            [b'*', b'*', rest @ ..] => (0..=t.len()).any(|i| go(rest, &t[i..])),
            [b'*', rest @ ..] => {
                let seg = t.iter().position(|&c| c == b'/').unwrap_or(t.len());
                (0..=seg).any(|i| go(rest, &t[i..]))
            }
            [c, rest @ ..] => t.first() == Some(c) && go(rest, &t[1..]),
        }
    }
    go(pattern.as_bytes(), topic.as_bytes())
}

/// Whether `topic` matches any of `patterns`.
pub fn matches_any(patterns: &[String], topic: &str) -> bool {
    patterns.iter().any(|p| matches(p, topic))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_star_stays_in_a_segment_and_double_star_crosses() {
        assert!(matches("camera/*/image", "camera/rear/image"));
        assert!(!matches("camera/*/image", "camera/rear/info"));
        assert!(matches("camera/**", "camera/rear/info"));
        assert!(matches("nav/*", "nav/subgoal"));
        assert!(!matches("nav/*", "nav/path/planned"));
        assert!(matches("nav/**", "nav/path/planned"));
        assert!(matches("state/pose", "state/pose"));
        assert!(!matches("state/pose", "state/poses"));
        assert!(matches("*/pose", "state/pose"));
        assert!(matches_any(&["x".into(), "cmd/*".into()], "cmd/velocity"));
    }
}
