//! Writes small ONNX models for tests, encoding the protobuf by hand (the
//! ONNX schema's field numbers), so tests need no Python and no download.
//!
//! [`mean_colour_linear`]: `image [1, 3, H, W]` -> ReduceMean over H, W ->
//! MatMul with a `[3, K]` weight -> `out [1, K]`: a "learned" model whose
//! output depends on the image's mean colour.

fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn key(field: u32, wire: u32, out: &mut Vec<u8>) {
    varint(((field << 3) | wire) as u64, out);
}

fn int(field: u32, v: i64, out: &mut Vec<u8>) {
    key(field, 0, out);
    varint(v as u64, out);
}

fn bytes(field: u32, b: &[u8], out: &mut Vec<u8>) {
    key(field, 2, out);
    varint(b.len() as u64, out);
    out.extend_from_slice(b);
}

fn msg(field: u32, f: impl FnOnce(&mut Vec<u8>), out: &mut Vec<u8>) {
    let mut inner = Vec::new();
    f(&mut inner);
    bytes(field, &inner, out);
}

const FLOAT: i64 = 1;

/// ValueInfoProto of a float tensor with fixed dims.
fn value_info(field: u32, name: &str, dims: &[i64], out: &mut Vec<u8>) {
    msg(
        field,
        |v| {
            bytes(1, name.as_bytes(), v);
            msg(
                2,
                |t| {
                    msg(
                        1,
                        |tt| {
                            int(1, FLOAT, tt);
                            msg(
                                2,
                                |shape| {
                                    for &d in dims {
                                        msg(1, |dim| int(1, d, dim), shape);
                                    }
                                },
                                tt,
                            );
                        },
                        t,
                    )
                },
                v,
            );
        },
        out,
    );
}

/// The model bytes; `weights` is `[3][K]` row-major (rows: R, G, B).
pub fn mean_colour_linear(height: i64, width: i64, weights: &[[f32; 3]]) -> Vec<u8> {
    let k = weights.len() as i64;
    let mut model = Vec::new();
    int(1, 8, &mut model); // ir_version
    bytes(2, b"farsight-tests", &mut model); // producer_name
    msg(
        7,
        |g| {
            // ReduceMean(image) over axes 2, 3 -> [1, 3]
            msg(
                1,
                |n| {
                    bytes(1, b"image", n);
                    bytes(2, b"mean", n);
                    bytes(3, b"reduce", n);
                    bytes(4, b"ReduceMean", n);
                    msg(
                        5,
                        |a| {
                            bytes(1, b"axes", a);
                            int(20, 7, a); // INTS
                            int(8, 2, a);
                            int(8, 3, a);
                        },
                        n,
                    );
                    msg(
                        5,
                        |a| {
                            bytes(1, b"keepdims", a);
                            int(20, 2, a); // INT
                            int(3, 0, a);
                        },
                        n,
                    );
                },
                g,
            );
            msg(
                1,
                |n| {
                    bytes(1, b"mean", n);
                    bytes(1, b"w", n);
                    bytes(2, b"out", n);
                    bytes(3, b"linear", n);
                    bytes(4, b"MatMul", n);
                },
                g,
            );
            bytes(2, b"mean_colour_linear", g);
            msg(
                5,
                |t| {
                    int(1, 3, t);
                    int(1, k, t);
                    int(2, FLOAT, t);
                    bytes(8, b"w", t);
                    let raw: Vec<u8> = (0..3)
                        .flat_map(|c| weights.iter().map(move |w| w[c]))
                        .flat_map(f32::to_le_bytes)
                        .collect();
                    bytes(9, &raw, t);
                },
                g,
            );
            value_info(11, "image", &[1, 3, height, width], g);
            value_info(12, "out", &[1, k], g);
        },
        &mut model,
    );
    msg(
        8,
        |o| {
            bytes(1, b"", o);
            int(2, 13, o);
        },
        &mut model,
    );
    model
}
