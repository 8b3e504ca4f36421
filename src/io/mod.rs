//! Output files: FITS images (hand-written writer, see `docs/dependencies.md`) and PNG (the
//! `png` crate), and the SHA-256 content hashes that name curves and configurations.

pub mod fits;

use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    File {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: PNG decoding failed: {source}")]
    PngRead {
        path: String,
        source: png::DecodingError,
    },
    #[error("{path}: a one-channel grayscale PNG, not {what}")]
    NotGray { path: String, what: String },
    #[error("{path}: PNG encoding failed: {source}")]
    Png {
        path: String,
        source: png::EncodingError,
    },
}

/// Writes a grayscale PNG: 8-bit when `bit_depth <= 8`, otherwise 16-bit holding the DN as
/// they are (a 12-bit image keeps values 0..4095).
pub fn write_png_gray(
    path: &Path,
    width: usize,
    height: usize,
    dn: &[u16],
    bit_depth: u32,
) -> Result<(), IoError> {
    write_png(path, encode_png_gray(width, height, dn, bit_depth))
}

/// Writes the PNG of [`encode_png_planes`]: one grey plane, three as RGB.
pub fn write_png_planes(
    path: &Path,
    width: usize,
    height: usize,
    dn: &[u16],
    bit_depth: u32,
    text: &[(&str, String)],
) -> Result<(), IoError> {
    write_png(path, encode_png_planes(width, height, dn, bit_depth, text))
}

/// Writes an 8-bit RGB PNG (`rgb` holds 3 bytes per pixel).
pub fn write_png_rgb(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), IoError> {
    let (color, depth) = (png::ColorType::Rgb, png::BitDepth::Eight);
    write_png(path, encode_png(width, height, color, depth, rgb))
}

/// An 8-bit RGB PNG in memory (`rgb` holds 3 bytes per pixel).
pub fn encode_png_rgb(
    width: usize,
    height: usize,
    rgb: &[u8],
) -> Result<Vec<u8>, png::EncodingError> {
    encode_png(
        width,
        height,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        rgb,
    )
}

/// Writes an encoded PNG to `path`, naming it in either error.
fn write_png(path: &Path, encoded: Result<Vec<u8>, png::EncodingError>) -> Result<(), IoError> {
    let p = path.display().to_string();
    let bytes = encoded.map_err(|source| IoError::Png {
        path: p.clone(),
        source,
    })?;
    std::fs::write(path, bytes).map_err(|source| IoError::File { path: p, source })
}

/// Decodes a one-channel grayscale PNG (8 or 16 bit) read from `path`: `(width, height, DN)`.
pub fn decode_png_gray(path: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<u16>), IoError> {
    let p = path.display().to_string();
    let dec_err = |source| IoError::PngRead {
        path: p.clone(),
        source,
    };
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(dec_err)?;
    let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let info = reader.next_frame(&mut buf).map_err(dec_err)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let dn: Vec<u16> = match (info.color_type, info.bit_depth) {
        (png::ColorType::Grayscale, png::BitDepth::Eight) => {
            buf[..w * h].iter().map(|&b| b as u16).collect()
        }
        (png::ColorType::Grayscale, png::BitDepth::Sixteen) => buf[..2 * w * h]
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect(),
        (c, d) => {
            return Err(IoError::NotGray {
                path: p,
                what: format!("{c:?} at {d:?}"),
            });
        }
    };
    Ok((w, h, dn))
}

/// A grayscale PNG in memory: 8-bit when `bit_depth <= 8`, else 16-bit holding the raw DN.
pub fn encode_png_gray(
    width: usize,
    height: usize,
    dn: &[u16],
    bit_depth: u32,
) -> Result<Vec<u8>, png::EncodingError> {
    encode_png_planes(width, height, dn, bit_depth, &[])
}

/// A camera's DN as `image.png`: one plane grey; three planes (a three-band camera's R, G,
/// B, one after the other) as an RGB image; any other count of planes stacked top to bottom
/// into one grey image `planes x height` rows tall. 8 bit up to `bit_depth` 8, else 16.
/// `text`: tEXt chunks (keyword, text), e.g. a mosaic's pattern.
pub fn encode_png_planes(
    width: usize,
    height: usize,
    dn: &[u16],
    bit_depth: u32,
    text: &[(&str, String)],
) -> Result<Vec<u8>, png::EncodingError> {
    let n = width * height;
    let planes = dn.len().checked_div(n).unwrap_or(1);
    // One plane, or any count but three: grey, the planes stacked (`height` rows each).
    let (color, rows, samples) = if planes == 3 {
        let rgb: Vec<u16> = (0..n)
            .flat_map(|i| [dn[i], dn[n + i], dn[2 * n + i]])
            .collect();
        (png::ColorType::Rgb, height, std::borrow::Cow::Owned(rgb))
    } else {
        let rows = height * planes.max(1);
        (
            png::ColorType::Grayscale,
            rows,
            std::borrow::Cow::Borrowed(dn),
        )
    };
    let (depth, data): (_, Vec<u8>) = if bit_depth <= 8 {
        let d = samples.iter().map(|&x| x.min(255) as u8).collect();
        (png::BitDepth::Eight, d)
    } else {
        (
            png::BitDepth::Sixteen,
            samples.iter().flat_map(|&x| x.to_be_bytes()).collect(),
        )
    };
    encode_png_text(width, rows, color, depth, &data, text)
}

/// Rows encoded between pause points.
const BAND_ROWS: usize = 64;

/// A PNG in memory from its samples, packed as the colour type and depth say.
fn encode_png(
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
) -> Result<Vec<u8>, png::EncodingError> {
    encode_png_text(width, height, color, depth, data, &[])
}

/// [`encode_png`] with tEXt chunks.
fn encode_png_text(
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
    text: &[(&str, String)],
) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(color);
    enc.set_depth(depth);
    for (k, t) in text {
        enc.add_text_chunk(k.to_string(), t.clone())?;
    }
    // Fast deflate: these images are written per frame; size matters less than time.
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header()?;
    // In bands of rows, with a pause point between them for the daemon's background
    // encoder (crate::background; nothing elsewhere).
    let row_bytes = data.len() / height.max(1);
    let mut stream = w.stream_writer_with_size((BAND_ROWS * row_bytes).max(1))?;
    for band in data.chunks((BAND_ROWS * row_bytes).max(1)) {
        crate::background::checkpoint();
        std::io::Write::write_all(&mut stream, band)?;
    }
    stream.finish()?;
    w.finish()?;
    Ok(out)
}

/// The SHA-256 of `bytes`, in hex: the content hash that names calibration curves and
/// configurations in reports.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    format!("{:x}", sha2::Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_png_encoded_in_bands_decodes_to_its_samples() {
        // 150 rows: two full bands of BAND_ROWS and a partial one, with pauses counted.
        let (w, h) = (37, 150);
        let dn: Vec<u16> = (0..w * h).map(|k| (k * 7919 % 65536) as u16).collect();
        let pauses = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let p = pauses.clone();
        let (dn2, bytes) = std::thread::spawn(move || {
            crate::background::install(std::sync::Arc::new(move || {
                p.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }));
            let bytes = encode_png_gray(w, h, &dn, 16).unwrap();
            (dn, bytes)
        })
        .join()
        .unwrap();
        assert_eq!(pauses.load(std::sync::atomic::Ordering::Relaxed), 3);
        let (w2, h2, back) = decode_png_gray(Path::new("mem"), &bytes).unwrap();
        assert_eq!((w2, h2), (w, h));
        assert_eq!(back, dn2);
    }
}
