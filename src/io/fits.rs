//! A minimal FITS writer (primary HDU, one 2-D image, IEEE float), after the FITS standard
//! 4.0: 2880-byte blocks, 80-character header cards, big-endian data. Written by hand because
//! the maintained Rust FITS writer (`fitsio`) wraps the C library cfitsio, a system dependency
//! for ~80 lines of format.

use super::IoError;
use std::path::Path;

/// A header value.
#[derive(Clone, Debug)]
pub enum Value {
    Int(i64),
    Float(f64),
    Str(String),
    Bool(bool),
}

/// One `KEY = value / comment` card (key at most 8 characters).
#[derive(Clone, Debug)]
pub struct Card {
    pub key: String,
    pub value: Value,
    pub comment: String,
}

impl Card {
    pub fn new(key: &str, value: Value, comment: &str) -> Self {
        Card {
            key: key.to_ascii_uppercase(),
            value,
            comment: comment.to_string(),
        }
    }
}

fn card(key: &str, value: &Value, comment: &str) -> String {
    let v = match value {
        Value::Int(i) => format!("{i:>20}"),
        Value::Float(f) if f.is_finite() => format!("{:>20}", format!("{f:.15E}")),
        Value::Float(_) => format!("{:>20}", "'NaN'"),
        Value::Bool(b) => format!("{:>20}", if *b { "T" } else { "F" }),
        Value::Str(s) => format!("{:<20}", format!("'{:<8}'", s.replace('\'', "''"))),
    };
    let mut c = format!("{:<8}= {} / {}", &key[..key.len().min(8)], v, comment);
    c.retain(|ch| ch.is_ascii() && !ch.is_ascii_control());
    c.truncate(80);
    format!("{c:<80}")
}

/// Precision of the stored floats.
#[derive(Clone, Copy, Debug)]
pub enum Bitpix {
    F32,
    F64,
}

/// Writes `data` (row-major from the top-left) as a `width x height` image, or as a cube of
/// such images one after the other (`NAXIS3` of them, a multi-band camera's bands) when
/// `data` holds several. FITS stores the first row at the bottom by convention; rows are
/// flipped so that viewers show the image the right way up, and the header says so
/// (`ROWORDER`).
pub fn write(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f64],
    bitpix: Bitpix,
    cards: &[Card],
) -> Result<(), IoError> {
    std::fs::write(path, encode(width, height, data, bitpix, cards)).map_err(|source| {
        IoError::File {
            path: path.display().to_string(),
            source,
        }
    })
}

/// The FITS file of [`write`] in memory.
pub fn encode(
    width: usize,
    height: usize,
    data: &[f64],
    bitpix: Bitpix,
    cards: &[Card],
) -> Vec<u8> {
    let mut header = String::new();
    header += &card("SIMPLE", &Value::Bool(true), "conforms to FITS standard");
    header += &card(
        "BITPIX",
        &Value::Int(match bitpix {
            Bitpix::F32 => -32,
            Bitpix::F64 => -64,
        }),
        "IEEE floating point",
    );
    let n = width * height;
    let planes = data.len().checked_div(n).unwrap_or(1).max(1);
    let naxis = if planes > 1 { 3 } else { 2 };
    header += &card("NAXIS", &Value::Int(naxis), "image, or a cube of bands");
    header += &card("NAXIS1", &Value::Int(width as i64), "columns (u)");
    header += &card("NAXIS2", &Value::Int(height as i64), "rows (v)");
    if planes > 1 {
        header += &card("NAXIS3", &Value::Int(planes as i64), "bands");
    }
    header += &card(
        "ROWORDER",
        &Value::Str("BOTTOM_UP".into()),
        "first stored row is the image bottom",
    );
    for c in cards {
        header += &card(&c.key, &c.value, &c.comment);
    }
    header += &format!("{:<80}", "END");
    while header.len() % 2880 != 0 {
        header.push(' ');
    }
    let mut bytes = header.into_bytes();
    for (p, row) in (0..planes).flat_map(|p| (0..height).rev().map(move |r| (p, r))) {
        let start = p * n + row * width;
        for &x in &data[start..start + width] {
            match bitpix {
                Bitpix::F32 => bytes.extend_from_slice(&(x as f32).to_be_bytes()),
                Bitpix::F64 => bytes.extend_from_slice(&x.to_be_bytes()),
            }
        }
    }
    while bytes.len() % 2880 != 0 {
        bytes.push(0);
    }
    bytes
}

/// Reads back an image written by [`write`]: `(width, height, data top-down, header text)`.
pub fn read(path: &Path) -> std::io::Result<(usize, usize, Vec<f64>, String)> {
    let bytes = std::fs::read(path)?;
    let bad = |m: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string());
    let mut pos = 0;
    let (mut bitpix, mut w, mut h) = (0i64, 0usize, 0usize);
    let mut header = String::new();
    loop {
        let c = std::str::from_utf8(
            bytes
                .get(pos..pos + 80)
                .ok_or_else(|| bad("truncated header"))?,
        )
        .map_err(|_| bad("non-ASCII header"))?;
        pos += 80;
        header += c;
        header.push('\n');
        let key = c[..8].trim();
        let val = c
            .get(10..)
            .unwrap_or("")
            .split('/')
            .next()
            .unwrap_or("")
            .trim();
        match key {
            "BITPIX" => bitpix = val.parse().map_err(|_| bad("BITPIX"))?,
            "NAXIS1" => w = val.parse().map_err(|_| bad("NAXIS1"))?,
            "NAXIS2" => h = val.parse().map_err(|_| bad("NAXIS2"))?,
            "END" => break,
            _ => {}
        }
    }
    pos = pos.div_ceil(2880) * 2880;
    let size = match bitpix {
        -32 => 4,
        -64 => 8,
        _ => return Err(bad("unsupported BITPIX")),
    };
    let mut data = vec![0.0; w * h];
    for row in 0..h {
        for col in 0..w {
            let o = pos + (row * w + col) * size;
            let b = bytes
                .get(o..o + size)
                .ok_or_else(|| bad("truncated data"))?;
            let x = if size == 4 {
                f32::from_be_bytes(b.try_into().unwrap()) as f64
            } else {
                f64::from_be_bytes(b.try_into().unwrap())
            };
            data[(h - 1 - row) * w + col] = x;
        }
    }
    Ok((w, h, data, header))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let dir = std::env::temp_dir().join(format!("optistim-fits-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.fits");
        let data: Vec<f64> = (0..12).map(|i| i as f64 * 0.5 - 1.0).collect();
        write(
            &path,
            4,
            3,
            &data,
            Bitpix::F64,
            &[Card::new("BUNIT", Value::Str("W".into()), "unit")],
        )
        .unwrap();
        let (w, h, back, header) = read(&path).unwrap();
        assert_eq!((w, h), (4, 3));
        assert_eq!(back, data);
        assert!(header.contains("BUNIT   = 'W       '"));
        assert_eq!(std::fs::metadata(&path).unwrap().len() % 2880, 0);
    }
}
