//! Compact BLOB codec for numeric arrays (DESIGN §6: little-endian f64/f32 with a shape header).
//!
//! Layout (all integers little-endian):
//!
//! | bytes | content |
//! |---|---|
//! | 0..2 | magic `b"RG"` |
//! | 2 | format version, `1` |
//! | 3 | element type: `1` = f64, `2` = f32 |
//! | 4 | rank `r` (0..=8; rank 0 is a scalar) |
//! | 5..8 | zero padding (keeps the dimensions 8-byte aligned) |
//! | 8..8+8r | the `r` dimensions as u64 |
//! | then | `prod(dims)` elements, row-major (C order: the last index varies fastest) |
//!
//! Decoding checks every field and that the length matches the shape exactly, so a truncated or
//! foreign blob is an error, never a silently wrong array. Store a matrix of `frames x joints`
//! with shape `[frames, joints]`; [`encode_matrix`]/[`decode_matrix`] convert nalgebra's
//! column-major `DMatrix` to and from this row-major layout.

use nalgebra::DMatrix;

const MAGIC: [u8; 2] = *b"RG";
const VERSION: u8 = 1;
const HEADER: usize = 8;
/// The largest rank a blob may have.
pub const MAX_RANK: usize = 8;

/// Errors decoding or encoding a numeric blob.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum BlobError {
    #[error("blob of {len} bytes is shorter than its {needed}-byte header")]
    TooShort { len: usize, needed: usize },
    #[error("blob does not start with the magic bytes \"RG\"")]
    BadMagic,
    #[error("blob format version {0} is not supported (expected 1)")]
    UnsupportedVersion(u8),
    #[error("blob holds element type {found}, expected {expected}")]
    WrongElementType { found: u8, expected: u8 },
    #[error("blob rank {0} exceeds the maximum of 8")]
    RankTooLarge(usize),
    #[error("shape {shape:?} has {expected} elements but {found} were given")]
    ShapeMismatch {
        shape: Vec<usize>,
        expected: usize,
        found: usize,
    },
    #[error("blob has rank {found}, expected rank {expected}")]
    WrongRank { found: usize, expected: usize },
    #[error("shape {0:?} overflows the addressable size")]
    ShapeOverflow(Vec<usize>),
    #[error("blob of {len} bytes does not match its shape {shape:?} ({expected} bytes expected)")]
    LengthMismatch {
        shape: Vec<usize>,
        len: usize,
        expected: usize,
    },
}

/// An element type a blob can hold.
pub trait Element: Copy + sealed::Sealed {
    /// The element-type tag of the header.
    const TAG: u8;
    /// Bytes per element.
    const SIZE: usize;
    #[doc(hidden)]
    fn write_le(self, out: &mut Vec<u8>);
    #[doc(hidden)]
    fn read_le(bytes: &[u8]) -> Self;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f64 {}
    impl Sealed for f32 {}
}

impl Element for f64 {
    const TAG: u8 = 1;
    const SIZE: usize = 8;
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn read_le(bytes: &[u8]) -> Self {
        f64::from_le_bytes(bytes.try_into().expect("chunk of 8 bytes"))
    }
}

impl Element for f32 {
    const TAG: u8 = 2;
    const SIZE: usize = 4;
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn read_le(bytes: &[u8]) -> Self {
        f32::from_le_bytes(bytes.try_into().expect("chunk of 4 bytes"))
    }
}

/// A decoded array: its shape and its row-major elements.
#[derive(Debug, Clone, PartialEq)]
pub struct Array<T> {
    pub shape: Vec<usize>,
    pub data: Vec<T>,
}

fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

/// Encodes `data` (row-major) with `shape`; the element count must equal the shape's product.
pub fn encode<T: Element>(shape: &[usize], data: &[T]) -> Result<Vec<u8>, BlobError> {
    if shape.len() > MAX_RANK {
        return Err(BlobError::RankTooLarge(shape.len()));
    }
    let expected = element_count(shape).ok_or_else(|| BlobError::ShapeOverflow(shape.to_vec()))?;
    if expected != data.len() {
        return Err(BlobError::ShapeMismatch {
            shape: shape.to_vec(),
            expected,
            found: data.len(),
        });
    }
    let mut out = Vec::with_capacity(HEADER + 8 * shape.len() + T::SIZE * data.len());
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.push(T::TAG);
    out.push(shape.len() as u8);
    out.extend_from_slice(&[0, 0, 0]);
    for &d in shape {
        out.extend_from_slice(&(d as u64).to_le_bytes());
    }
    for &x in data {
        x.write_le(&mut out);
    }
    Ok(out)
}

/// Decodes a blob written by [`encode`] with the same element type.
pub fn decode<T: Element>(bytes: &[u8]) -> Result<Array<T>, BlobError> {
    if bytes.len() < HEADER {
        return Err(BlobError::TooShort {
            len: bytes.len(),
            needed: HEADER,
        });
    }
    if bytes[0..2] != MAGIC {
        return Err(BlobError::BadMagic);
    }
    if bytes[2] != VERSION {
        return Err(BlobError::UnsupportedVersion(bytes[2]));
    }
    if bytes[3] != T::TAG {
        return Err(BlobError::WrongElementType {
            found: bytes[3],
            expected: T::TAG,
        });
    }
    let rank = bytes[4] as usize;
    if rank > MAX_RANK {
        return Err(BlobError::RankTooLarge(rank));
    }
    let data_start = HEADER + 8 * rank;
    if bytes.len() < data_start {
        return Err(BlobError::TooShort {
            len: bytes.len(),
            needed: data_start,
        });
    }
    let mut shape = Vec::with_capacity(rank);
    for chunk in bytes[HEADER..data_start].chunks_exact(8) {
        let d = u64::from_le_bytes(chunk.try_into().expect("chunk of 8 bytes"));
        let d = usize::try_from(d).map_err(|_| BlobError::ShapeOverflow(shape.clone()))?;
        shape.push(d);
    }
    let count = element_count(&shape)
        .filter(|n| n.checked_mul(T::SIZE).is_some())
        .ok_or_else(|| BlobError::ShapeOverflow(shape.clone()))?;
    let expected = data_start + count * T::SIZE;
    if bytes.len() != expected {
        return Err(BlobError::LengthMismatch {
            shape,
            len: bytes.len(),
            expected,
        });
    }
    let data = bytes[data_start..]
        .chunks_exact(T::SIZE)
        .map(T::read_le)
        .collect();
    Ok(Array { shape, data })
}

/// Encodes a matrix as shape `[nrows, ncols]`, row-major.
pub fn encode_matrix(m: &DMatrix<f64>) -> Vec<u8> {
    let (rows, cols) = m.shape();
    // The transpose's column-major storage is the original's row-major order.
    let row_major: Vec<f64> = m.transpose().as_slice().to_vec();
    encode(&[rows, cols], &row_major).expect("a matrix's shape matches its element count")
}

/// Decodes a rank-2 f64 blob into a matrix (`[nrows, ncols]`, row-major).
pub fn decode_matrix(bytes: &[u8]) -> Result<DMatrix<f64>, BlobError> {
    let a = decode::<f64>(bytes)?;
    match a.shape.as_slice() {
        &[rows, cols] => Ok(DMatrix::from_row_slice(rows, cols, &a.data)),
        _ => Err(BlobError::WrongRank {
            found: a.shape.len(),
            expected: 2,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f64_arrays_round_trip_bit_exactly_including_special_values() {
        let data = [
            0.0,
            -0.0,
            1.5,
            -2.25e-300,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            std::f64::consts::PI,
            1e-320, // subnormal
            42.0,
            -7.0,
        ];
        let bytes = encode(&[3, 4], &data).unwrap();
        assert_eq!(bytes.len(), 8 + 2 * 8 + 12 * 8);
        let back = decode::<f64>(&bytes).unwrap();
        assert_eq!(back.shape, vec![3, 4]);
        let same_bits = back
            .data
            .iter()
            .zip(&data)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same_bits);
        let nan = decode::<f64>(&encode(&[1], &[f64::NAN]).unwrap()).unwrap();
        assert!(nan.data[0].is_nan());
    }

    #[test]
    fn f32_arrays_round_trip_and_are_half_the_size() {
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.125 - 1.0).collect();
        let bytes = encode(&[2, 3, 4], &data).unwrap();
        assert_eq!(bytes.len(), 8 + 3 * 8 + 24 * 4);
        let back = decode::<f32>(&bytes).unwrap();
        assert_eq!(
            back,
            Array {
                shape: vec![2, 3, 4],
                data
            }
        );
    }

    #[test]
    fn scalars_and_empty_arrays_round_trip() {
        let s = decode::<f64>(&encode(&[], &[2.5]).unwrap()).unwrap();
        assert_eq!(
            s,
            Array {
                shape: vec![],
                data: vec![2.5]
            }
        );
        let e = decode::<f64>(&encode::<f64>(&[0, 7], &[]).unwrap()).unwrap();
        assert_eq!(
            e,
            Array {
                shape: vec![0, 7],
                data: vec![]
            }
        );
    }

    #[test]
    fn the_header_is_little_endian_as_documented() {
        let bytes = encode(&[2], &[1.0f64, 2.0]).unwrap();
        assert_eq!(&bytes[0..8], &[b'R', b'G', 1, 1, 1, 0, 0, 0]);
        assert_eq!(&bytes[8..16], &2u64.to_le_bytes());
        assert_eq!(&bytes[16..24], &1.0f64.to_le_bytes());
    }

    #[test]
    fn matrices_round_trip_in_row_major_order() {
        let m = DMatrix::from_fn(3, 5, |i, j| (10 * i + j) as f64);
        let bytes = encode_matrix(&m);
        let raw = decode::<f64>(&bytes).unwrap();
        // Row-major: the second stored element is (row 0, column 1).
        assert_eq!(raw.data[1], 1.0);
        assert_eq!(raw.data[5], 10.0);
        assert_eq!(decode_matrix(&bytes).unwrap(), m);
    }

    #[test]
    fn bad_blobs_are_rejected_with_the_reason() {
        assert_eq!(
            encode(&[2, 2], &[1.0f64; 3]),
            Err(BlobError::ShapeMismatch {
                shape: vec![2, 2],
                expected: 4,
                found: 3
            })
        );
        assert!(matches!(
            encode(&[1; 9], &[1.0f64]),
            Err(BlobError::RankTooLarge(9))
        ));
        assert!(matches!(
            encode::<f64>(&[usize::MAX, 2], &[]),
            Err(BlobError::ShapeOverflow(_))
        ));
        let good = encode(&[2], &[1.0f64, 2.0]).unwrap();
        assert!(matches!(
            decode::<f64>(&good[..5]),
            Err(BlobError::TooShort { .. })
        ));
        assert!(matches!(
            decode::<f64>(&good[..good.len() - 1]),
            Err(BlobError::LengthMismatch { .. })
        ));
        let mut longer = good.clone();
        longer.push(0);
        assert!(matches!(
            decode::<f64>(&longer),
            Err(BlobError::LengthMismatch { .. })
        ));
        assert_eq!(
            decode::<f32>(&good),
            Err(BlobError::WrongElementType {
                found: 1,
                expected: 2
            })
        );
        let mut bad = good.clone();
        bad[0] = b'X';
        assert_eq!(decode::<f64>(&bad), Err(BlobError::BadMagic));
        let mut bad = good.clone();
        bad[2] = 9;
        assert_eq!(decode::<f64>(&bad), Err(BlobError::UnsupportedVersion(9)));
        let mut bad = good;
        bad[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(decode::<f64>(&bad).is_err());
        assert!(decode_matrix(&encode(&[4], &[1.0f64; 4]).unwrap()).is_err());
    }
}
