//! Screen calibration curves: measured screen DN -> F_eff at the camera [W/m^2], per channel.
//!
//! The file format (`calibration/README.md` documents it for the people who measure):
//!
//! ```text
//! # optistim screen calibration v1
//! # date: 2026-11-20
//! # facility: ESTEC optical lab, RETINA bench 2
//! # method: uniform frames, flight camera mean over the central 200 x 200 px
//! # dn_full_scale: 255
//! dn,feff_w_m2                      (or dn,feff_r_w_m2,feff_g_w_m2,feff_b_w_m2)
//! 0,2.0e-9
//! 16,2.6e-9
//! ...
//! ```
//!
//! The data rows are read with the `csv` crate, the `#` lines by hand (they carry the
//! provenance). Validation refuses (with the file, line and value): a missing provenance line,
//! columns that are not `dn` then `feff_*_w_m2` (the unit is part of the name), fewer than
//! [`MIN_POINTS`] rows,
//! non-finite or negative values, DN not strictly increasing, F_eff not strictly increasing
//! (a screen whose light does not grow with DN cannot be inverted). Interpolation is linear or
//! monotone cubic (Fritsch-Carlson, PCHIP-like); both keep the curve monotone, so the inverse
//! F_eff -> DN is unique. Each curve has an id (the file stem) and a SHA-256 of its content, which
//! every frame reports.

use super::colour::{Crosstalk, PRIMARIES};
use super::dither::Dither;
use std::path::Path;

/// Fewest measured points a curve may have.
pub const MIN_POINTS: usize = 4;

/// A calibration path of the form `builtin:NAME` names a curve built into the binary (the
/// daemon's embedded default configuration uses `builtin:example_gamma22`).
pub const BUILTIN: &str = "builtin:";
/// `calibration/example_gamma22.csv`, built in.
pub const EXAMPLE_GAMMA22: &str = include_str!("../../calibration/example_gamma22.csv");

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CalibrationError {
    #[error("{file}: cannot read: {message}")]
    Read { file: String, message: String },
    #[error("{file}: line {line}: {message}")]
    Bad {
        file: String,
        line: usize,
        message: String,
    },
}

/// Interpolation between the measured points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Interp {
    Linear,
    /// Monotone piecewise cubic Hermite (Fritsch-Carlson slopes).
    #[default]
    Pchip,
}

/// Where and how the curve was measured.
#[derive(Clone, Debug, PartialEq, Default, serde::Serialize)]
pub struct Provenance {
    pub date: String,
    pub facility: String,
    pub method: String,
}

/// One channel's response.
#[derive(Clone, Debug, PartialEq)]
struct Channel {
    name: String,
    feff_w_m2: Vec<f64>,
    /// Hermite slopes d F_eff / d DN at the points (PCHIP).
    slopes: Vec<f64>,
}

/// A validated calibration curve.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    pub id: String,
    /// SHA-256 of the file's bytes, hex.
    pub sha256: String,
    pub provenance: Provenance,
    pub interp: Interp,
    /// The screen's highest DN in the measurement (255 for 8 bit): the DN axis is read as a
    /// fraction of it, so an 8-bit measurement drives a 10-bit output too.
    pub dn_full_scale: f64,
    dn: Vec<f64>,
    channels: Vec<Channel>,
    /// A colour screen's cross-talk, one row per camera band (by name): the band's F_eff per
    /// unit of each channel's F_eff column [dimensionless], in column order.
    pub crosstalk: Vec<(String, Vec<f64>)>,
}

/// Pixels clipped by the inversion, reported with every frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ClipCounts {
    /// No light at all (F_eff = 0, e.g. the sky): shown at the lowest DN, which emits the
    /// screen's dark level. Not a clip, but the floor the camera sees there.
    pub black: u64,
    /// F_eff above zero but below the screen's dark level (or not a number): shown at the
    /// lowest DN.
    pub below_dark: u64,
    /// F_eff above the screen's maximum: shown at the highest DN.
    pub above_max: u64,
}

impl Curve {
    pub fn load(path: &Path, interp: Interp) -> Result<Curve, CalibrationError> {
        let file = path.display().to_string();
        if let Some(name) = file.strip_prefix(BUILTIN) {
            return match name {
                "example_gamma22" => Curve::parse(EXAMPLE_GAMMA22.as_bytes(), name, &file, interp),
                _ => Err(CalibrationError::Read {
                    file: file.clone(),
                    message: "unknown built-in curve; built in: example_gamma22".into(),
                }),
            };
        }
        let bytes = std::fs::read(path).map_err(|e| CalibrationError::Read {
            file: file.clone(),
            message: e.to_string(),
        })?;
        let id = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| file.clone());
        Curve::parse(&bytes, &id, &file, interp)
    }

    /// Parses and validates curve bytes; `file` names them in errors.
    pub fn parse(
        bytes: &[u8],
        id: &str,
        file: &str,
        interp: Interp,
    ) -> Result<Curve, CalibrationError> {
        let bad = |line: usize, message: String| CalibrationError::Bad {
            file: file.to_string(),
            line,
            message,
        };
        let text = std::str::from_utf8(bytes).map_err(|e| bad(0, format!("not UTF-8: {e}")))?;
        let Header {
            magic,
            provenance: prov,
            full_scale,
            crosstalk,
        } = read_header(text).map_err(|(line, m)| bad(line, m))?;
        let (names, rows) = read_rows(bytes).map_err(|(line, m)| bad(line, m))?;
        for (line, band, row) in &crosstalk {
            if names.len() < 3 {
                return Err(bad(
                    *line,
                    format!("crosstalk {band}: a grey screen (one F_eff column) has no cross-talk"),
                ));
            }
            if row.len() != names.len() - 1 {
                return Err(bad(
                    *line,
                    format!(
                        "crosstalk {band}: {} values, the file has {} F_eff columns",
                        row.len(),
                        names.len() - 1
                    ),
                ));
            }
            if crosstalk.iter().filter(|(_, b, _)| b == band).count() > 1 {
                return Err(bad(*line, format!("crosstalk {band}: given twice")));
            }
        }
        if !magic {
            return Err(bad(
                1,
                "missing \"# optistim screen calibration v1\"".into(),
            ));
        }
        for (k, v) in [
            ("date", &prov.date),
            ("facility", &prov.facility),
            ("method", &prov.method),
        ] {
            if v.is_empty() {
                return Err(bad(1, format!("missing provenance line \"# {k}: ...\"")));
            }
        }
        let Some(full_scale) = full_scale else {
            return Err(bad(
                1,
                "missing \"# dn_full_scale: N\" (the screen's highest DN in the measurement)"
                    .into(),
            ));
        };
        if rows.len() < MIN_POINTS {
            return Err(bad(
                0,
                format!("{} points: at least {MIN_POINTS} are needed", rows.len()),
            ));
        }
        if let Some((line, r)) = rows.iter().find(|(_, r)| r[0] > full_scale) {
            return Err(bad(
                *line,
                format!("dn = {} above dn_full_scale = {full_scale}", r[0]),
            ));
        }
        for w in rows.windows(2) {
            let ((_, a), (line, b)) = (&w[0], &w[1]);
            if b[0] <= a[0] {
                return Err(bad(
                    *line,
                    format!(
                        "dn = {} after {}: DN must increase strictly (sort the rows)",
                        b[0], a[0]
                    ),
                ));
            }
            for c in 1..names.len() {
                if b[c] <= a[c] {
                    return Err(bad(
                        *line,
                        format!(
                            "{} = {:e} after {:e}: F_eff must increase strictly with DN (non-monotonic response cannot be inverted)",
                            names[c], b[c], a[c]
                        ),
                    ));
                }
            }
        }
        let dn: Vec<f64> = rows.iter().map(|r| r.1[0]).collect();
        let channels = (1..names.len())
            .map(|c| {
                let f: Vec<f64> = rows.iter().map(|r| r.1[c]).collect();
                Channel {
                    name: names[c].clone(),
                    slopes: pchip_slopes(&dn, &f),
                    feff_w_m2: f,
                }
            })
            .collect();
        Ok(Curve {
            id: id.to_string(),
            sha256: crate::io::sha256_hex(bytes),
            provenance: prov,
            interp,
            dn_full_scale: full_scale,
            dn,
            channels,
            crosstalk: crosstalk.into_iter().map(|(_, b, r)| (b, r)).collect(),
        })
    }

    pub fn channels(&self) -> usize {
        self.channels.len()
    }

    pub fn channel_name(&self, c: usize) -> &str {
        &self.channels[c].name
    }

    /// Measured DN range `(lowest, highest)`.
    pub fn dn_range(&self) -> (f64, f64) {
        (self.dn[0], *self.dn.last().unwrap_or(&self.dn[0]))
    }

    /// F_eff range of channel `c`: the dark level and the maximum [W/m^2].
    pub fn feff_range(&self, c: usize) -> (f64, f64) {
        let f = &self.channels[c].feff_w_m2;
        (f[0], f[f.len() - 1])
    }

    /// F_eff [W/m^2] shown at (fractional) `dn` by channel `c`, clamped to the measured range.
    pub fn feff_at(&self, c: usize, dn: f64) -> f64 {
        let ch = &self.channels[c];
        let (x, y) = (&self.dn, &ch.feff_w_m2);
        let dn = dn.clamp(x[0], x[x.len() - 1]);
        let i = x.partition_point(|&v| v <= dn).clamp(1, x.len() - 1) - 1;
        let h = x[i + 1] - x[i];
        let t = (dn - x[i]) / h;
        match self.interp {
            Interp::Linear => y[i] + t * (y[i + 1] - y[i]),
            Interp::Pchip => hermite(y[i], y[i + 1], ch.slopes[i] * h, ch.slopes[i + 1] * h, t),
        }
    }

    /// The (fractional) DN at which channel `c` shows `feff` [W/m^2]; `None` outside the
    /// measured range (which [`Curve::invert_image`] clips and counts).
    pub fn dn_for(&self, c: usize, feff: f64) -> Option<f64> {
        let ch = &self.channels[c];
        let (x, y) = (&self.dn, &ch.feff_w_m2);
        if !(feff >= y[0] && feff <= y[y.len() - 1]) {
            return None;
        }
        let i = y.partition_point(|&v| v <= feff).clamp(1, y.len() - 1) - 1;
        let h = x[i + 1] - x[i];
        match self.interp {
            Interp::Linear => Some(x[i] + h * (feff - y[i]) / (y[i + 1] - y[i])),
            Interp::Pchip => {
                // The segment is monotone: bisection on t, 50 steps reach 1e-15 of a segment.
                let (m0, m1) = (ch.slopes[i] * h, ch.slopes[i + 1] * h);
                let (mut lo, mut hi) = (0.0f64, 1.0f64);
                for _ in 0..50 {
                    let mid = 0.5 * (lo + hi);
                    if hermite(y[i], y[i + 1], m0, m1, mid) < feff {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                Some(x[i] + h * 0.5 * (lo + hi))
            }
        }
    }

    /// The inverse of channel `c` for `levels` output codes (256 for 8 bit, 1024 for 10 bit)
    /// spanning the curve's DN range as fractions of full scale: F_eff at every quarter code.
    pub fn inverse(&self, c: usize, levels: u32) -> Inverse {
        let top = (levels - 1) as f64;
        let (lo, hi) = self.dn_range();
        let code_lo = (lo / self.dn_full_scale * top).ceil();
        let code_hi = (hi / self.dn_full_scale * top).floor().min(top);
        let steps = ((code_hi - code_lo) * INVERSE_SUBSTEPS) as u32;
        let feff = (0..=steps)
            .map(|k| {
                let code = code_lo + k as f64 / INVERSE_SUBSTEPS;
                self.feff_at(c, code / top * self.dn_full_scale)
            })
            .collect();
        Inverse {
            code_lo,
            feff,
            range: self.feff_range(c),
        }
    }

    /// Screen DN for an F_eff image on channel `c` (see [`Inverse::apply`]).
    pub fn invert_image(
        &self,
        c: usize,
        feff: &[f64],
        width: usize,
        levels: u32,
        dither: Dither,
        out: &mut Vec<u16>,
    ) -> ClipCounts {
        self.inverse(c, levels).apply(feff, width, dither, out)
    }
}

/// Table entries per output code in [`Inverse`].
pub const INVERSE_SUBSTEPS: f64 = 4.0;

/// A curve's inverse at the codes of one output depth: F_eff at every quarter code, increasing.
#[derive(Clone, Debug, PartialEq)]
pub struct Inverse {
    code_lo: f64,
    feff: Vec<f64>,
    /// The curve's F_eff range: dark level and maximum [W/m^2].
    range: (f64, f64),
}

impl Inverse {
    /// F_eff [W/m^2] at codes `code_lo + k / INVERSE_SUBSTEPS`, increasing.
    pub fn table(&self) -> &[f64] {
        &self.feff
    }

    /// The lowest and highest codes the curve reaches.
    pub fn codes(&self) -> (f64, f64) {
        (
            self.code_lo,
            self.code_lo + (self.feff.len() - 1) as f64 / INVERSE_SUBSTEPS,
        )
    }

    /// The curve's F_eff range: dark level and maximum [W/m^2].
    pub fn range(&self) -> (f64, f64) {
        self.range
    }

    /// The fractional code showing `f` (inside the curve's range): the quarter code below by
    /// bisection, the rest by linear interpolation (within 0.01 code of the exact inverse of
    /// the example curve, whose gamma bends most near code 0: unit test).
    #[inline]
    pub fn code(&self, f: f64) -> f64 {
        let t = &self.feff;
        let k = t.partition_point(|&v| v <= f);
        let top = self.code_lo + (t.len() - 1) as f64 / INVERSE_SUBSTEPS;
        if k == 0 {
            return self.code_lo;
        }
        if k == t.len() {
            return top;
        }
        let (a, b) = (t[k - 1], t[k]);
        self.code_lo + ((k - 1) as f64 + (f - a) / (b - a)) / INVERSE_SUBSTEPS
    }

    /// Screen codes for an F_eff image (`width` px per row), rounded or dithered, in
    /// parallel over rows. Pixels with no light at all show the lowest code and are counted
    /// as `black`; those between zero and the dark level, or above the maximum, are clipped to
    /// the end codes and counted.
    pub fn apply(
        &self,
        feff: &[f64],
        width: usize,
        dither: Dither,
        out: &mut Vec<u16>,
    ) -> ClipCounts {
        use rayon::prelude::*;
        let width = width.max(1);
        out.clear();
        out.resize(feff.len(), 0);
        out.par_chunks_mut(width)
            .zip(feff.par_chunks(width))
            .enumerate()
            .map(|(j, (row_out, row))| {
                let mut clips = ClipCounts::default();
                for (i, (o, &f)) in row_out.iter_mut().zip(row).enumerate() {
                    *o = self.quantise(clips.classify(f, self.range), f, dither, i, j);
                }
                clips
            })
            .reduce(ClipCounts::default, ClipCounts::merge)
    }

    /// The code of `f` at pixel `(i, j)` placed `place` against the curve's range: rounded
    /// or dithered inside, the end codes outside.
    #[inline(always)]
    fn quantise(&self, place: Place, f: f64, dither: Dither, i: usize, j: usize) -> u16 {
        let (c_lo, c_hi) = self.codes();
        (match place {
            Place::Inside => dither.quantise(self.code(f), i, j).clamp(c_lo, c_hi),
            Place::Above => c_hi,
            Place::Below => c_lo,
        }) as u16
    }

    /// The clip counts [`Inverse::apply`] would report for `feff`, without the codes (for a
    /// frame the GPU inverts).
    pub fn count_clips(&self, feff: &[f64]) -> ClipCounts {
        use rayon::prelude::*;
        feff.par_chunks(4096)
            .map(|chunk| {
                let mut clips = ClipCounts::default();
                chunk.iter().for_each(|&f| {
                    clips.classify(f, self.range);
                });
                clips
            })
            .reduce(ClipCounts::default, ClipCounts::merge)
    }
}

/// A colour screen's codes for a region's F_eff of every camera band (`bands` planes of
/// `width`-pixel rows, band after band): per pixel the primaries' F_eff solved through the
/// cross-talk ([`Crosstalk::primaries`]), each inverted through its own curve (`inverses`: R,
/// G, B) and rounded or dithered as [`Inverse::apply`] does. Writes three planes (R, G, B) of
/// the region's size. A pixel is counted once: `black` when every band is dark, `above_max`
/// when a primary exceeds its maximum, else `below_dark` when one falls below its dark level
/// (a colour outside the primaries' gamut counts here too).
///
/// `dither_shift`: the dither pattern is read at `(i >> shift, j >> shift)`. A Bayer camera
/// seeing the screen pixel for pixel records each band on one phase of the 2 x 2 lattice;
/// the 8 x 8 ordered pattern puts a quarter of its thresholds on each phase (those below
/// 1/4 on one), so every band would see a biased quarter (-0.5 % on R, measured). With a
/// shift of 1 each phase sees the whole pattern.
pub fn apply_colour(
    crosstalk: &Crosstalk,
    inverses: &[Inverse],
    region: &[f64],
    width: usize,
    (dither, dither_shift): (Dither, u32),
    out: &mut Vec<u16>,
) -> ClipCounts {
    use rayon::prelude::*;
    let width = width.max(1);
    let n = region.len() / crosstalk.bands().max(1);
    out.clear();
    out.resize(PRIMARIES * n, 0);
    let (r, rest) = out.split_at_mut(n);
    let (g, b) = rest.split_at_mut(n);
    r.par_chunks_mut(width)
        .zip(g.par_chunks_mut(width))
        .zip(b.par_chunks_mut(width))
        .enumerate()
        .map(|(j, ((r, g), b))| {
            let mut clips = ClipCounts::default();
            for i in 0..r.len() {
                let (f, places) =
                    clips.classify_colour(crosstalk, inverses, region, n, j * width + i);
                let (di, dj) = (i >> dither_shift, j >> dither_shift);
                r[i] = inverses[0].quantise(places[0], f[0], dither, di, dj);
                g[i] = inverses[1].quantise(places[1], f[1], dither, di, dj);
                b[i] = inverses[2].quantise(places[2], f[2], dither, di, dj);
            }
            clips
        })
        .reduce(ClipCounts::default, ClipCounts::merge)
}

/// The clip counts [`apply_colour`] would report, without the codes (for a frame the GPU
/// inverts).
pub fn count_colour_clips(
    crosstalk: &Crosstalk,
    inverses: &[Inverse],
    region: &[f64],
) -> ClipCounts {
    use rayon::prelude::*;
    let n = region.len() / crosstalk.bands().max(1);
    (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .fold(ClipCounts::default, |mut clips, p| {
            clips.classify_colour(crosstalk, inverses, region, n, p);
            clips
        })
        .reduce(ClipCounts::default, ClipCounts::merge)
}

/// Where an F_eff value falls against the screen's range.
#[derive(Clone, Copy)]
enum Place {
    Inside,
    Below,
    Above,
}

impl Place {
    /// `f` against `[f_lo, f_hi]`; a NaN is below.
    #[inline(always)]
    fn of(f: f64, (f_lo, f_hi): (f64, f64)) -> Place {
        if f >= f_lo && f <= f_hi {
            Place::Inside
        } else if f > f_hi {
            Place::Above
        } else {
            Place::Below
        }
    }
}

impl ClipCounts {
    /// Places `f` against `[f_lo, f_hi]` and counts it when it is outside: no light at all is
    /// `black`, above zero (or negative, or NaN: never expected) but below the dark level is
    /// `below_dark`, above the maximum `above_max`.
    #[inline(always)]
    fn classify(&mut self, f: f64, range: (f64, f64)) -> Place {
        let place = Place::of(f, range);
        match place {
            Place::Inside => {}
            Place::Above => self.above_max += 1,
            Place::Below if f == 0.0 => self.black += 1,
            Place::Below => self.below_dark += 1,
        }
        place
    }

    /// Solves pixel `p` of a region (`n` pixels per band plane) for the primaries' F_eff and
    /// places each against its curve's range, counting the pixel once ([`apply_colour`]).
    #[inline(always)]
    fn classify_colour(
        &mut self,
        crosstalk: &Crosstalk,
        inverses: &[Inverse],
        region: &[f64],
        n: usize,
        p: usize,
    ) -> ([f64; PRIMARIES], [Place; PRIMARIES]) {
        let f = crosstalk.primaries(|b| region[b * n + p]);
        let places = [0, 1, 2].map(|c| Place::of(f[c], inverses[c].range));
        if (0..crosstalk.bands()).all(|b| region[b * n + p] == 0.0) {
            self.black += 1;
        } else if places.iter().any(|p| matches!(p, Place::Above)) {
            self.above_max += 1;
        } else if places.iter().any(|p| matches!(p, Place::Below)) {
            self.below_dark += 1;
        }
        (f, places)
    }

    fn merge(a: ClipCounts, b: ClipCounts) -> ClipCounts {
        ClipCounts {
            black: a.black + b.black,
            below_dark: a.below_dark + b.below_dark,
            above_max: a.above_max + b.above_max,
        }
    }
}

/// What the `#` lines say.
struct Header {
    magic: bool,
    provenance: Provenance,
    full_scale: Option<f64>,
    /// `(line, band, row)` of each `# crosstalk BAND: x, y, z` line.
    crosstalk: Vec<(usize, String, Vec<f64>)>,
}

/// Reads the `#` lines: the format line, provenance and `dn_full_scale`. Errors carry the line.
fn read_header(text: &str) -> Result<Header, (usize, String)> {
    let mut h = Header {
        magic: false,
        provenance: Provenance::default(),
        full_scale: None,
        crosstalk: Vec::new(),
    };
    for (n, raw) in text.lines().enumerate() {
        let Some(c) = raw.trim().strip_prefix('#') else {
            continue;
        };
        let (line, c) = (n + 1, c.trim());
        if c.starts_with("optistim screen calibration") {
            if !c.ends_with("v1") {
                return Err((
                    line,
                    format!("unsupported format \"{c}\": this build reads v1"),
                ));
            }
            h.magic = true;
            continue;
        }
        let Some((k, v)) = c.split_once(':') else {
            continue;
        };
        let v = v.trim().to_string();
        if let Some(band) = k.trim().strip_prefix("crosstalk ") {
            let row = v
                .split(',')
                .map(|x| {
                    let x = x.trim();
                    x.parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite() && *x >= 0.0)
                        .ok_or((
                            line,
                            format!("crosstalk {}: \"{x}\" is not a number >= 0", band.trim()),
                        ))
                })
                .collect::<Result<Vec<f64>, _>>()?;
            h.crosstalk.push((line, band.trim().to_string(), row));
            continue;
        }
        match k.trim() {
            "date" => h.provenance.date = v,
            "facility" => h.provenance.facility = v,
            "method" => h.provenance.method = v,
            "dn_full_scale" => {
                let x = v.parse::<f64>().ok().filter(|x| x.is_finite() && *x >= 1.0);
                let allowed = "a number >= 1 (255 for an 8-bit screen, 1023 for 10-bit)";
                h.full_scale =
                    Some(x.ok_or((line, format!("dn_full_scale = \"{v}\": {allowed}")))?);
            }
            _ => {}
        }
    }
    Ok(h)
}

/// Reads the column names and the data rows `(line, values)` with the `csv` crate (`#` lines
/// are comments), checking names, column counts and that every value is a finite number >= 0.
#[allow(clippy::type_complexity)]
fn read_rows(bytes: &[u8]) -> Result<(Vec<String>, Vec<(usize, Vec<f64>)>), (usize, String)> {
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(bytes);
    let csv_err = |e: csv::Error| {
        let line = e.position().map_or(0, |p| p.line() as usize);
        (line, e.to_string())
    };
    let head = rdr.headers().map_err(csv_err)?.clone();
    let head_line = head.position().map_or(0, |p| p.line() as usize);
    let names: Vec<String> = head.iter().map(str::to_string).collect();
    if names.first().map(String::as_str) != Some("dn") || names.len() < 2 {
        let row = names.join(",");
        return Err((
            head_line,
            format!(
                "header \"{row}\": expected \"dn,feff_w_m2\" or \"dn,feff_<channel>_w_m2,...\""
            ),
        ));
    }
    if let Some(c) = names[1..]
        .iter()
        .find(|c| !(c.starts_with("feff") && c.ends_with("_w_m2")))
    {
        return Err((
            head_line,
            format!(
                "column \"{c}\": F_eff columns are named feff[_channel]_w_m2 (W/m^2 at the camera)"
            ),
        ));
    }
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(csv_err)?;
        let line = rec.position().map_or(0, |p| p.line() as usize);
        if rec.len() != names.len() {
            return Err((
                line,
                format!(
                    "{} values, the header has {} columns",
                    rec.len(),
                    names.len()
                ),
            ));
        }
        let vals = rec
            .iter()
            .zip(&names)
            .map(|(c, name)| match c.parse::<f64>() {
                Err(_) => Err((line, format!("{name} = \"{c}\" is not a number"))),
                Ok(v) if !v.is_finite() || v < 0.0 => {
                    Err((line, format!("{name} = {c}: must be finite and >= 0")))
                }
                Ok(v) => Ok(v),
            })
            .collect::<Result<Vec<f64>, _>>()?;
        rows.push((line, vals));
    }
    Ok((names, rows))
}

#[inline(always)]
fn hermite(y0: f64, y1: f64, m0: f64, m1: f64, t: f64) -> f64 {
    let (t2, t3) = (t * t, t * t * t);
    (2.0 * t3 - 3.0 * t2 + 1.0) * y0
        + (t3 - 2.0 * t2 + t) * m0
        + (-2.0 * t3 + 3.0 * t2) * y1
        + (t3 - t2) * m1
}

/// Fritsch-Carlson monotone slopes (the PCHIP of Fritsch & Butland, 1984).
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let d: Vec<f64> = (0..n - 1)
        .map(|i| (y[i + 1] - y[i]) / (x[i + 1] - x[i]))
        .collect();
    let mut m = vec![0.0; n];
    m[0] = d[0];
    m[n - 1] = d[n - 2];
    for i in 1..n - 1 {
        if d[i - 1] * d[i] <= 0.0 {
            m[i] = 0.0;
        } else {
            let (h0, h1) = (x[i] - x[i - 1], x[i + 1] - x[i]);
            let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
            m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i]);
        }
    }
    m
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub const EXAMPLE: &str = super::EXAMPLE_GAMMA22;

    fn curve(text: &str, interp: Interp) -> Result<Curve, CalibrationError> {
        Curve::parse(text.as_bytes(), "t", "t.csv", interp)
    }

    #[test]
    fn the_example_curve_loads_and_inverts_both_ways() {
        for interp in [Interp::Linear, Interp::Pchip] {
            let c = curve(EXAMPLE, interp).unwrap();
            assert_eq!(c.sha256.len(), 64);
            assert!(c.provenance.facility.contains("synthetic"));
            let (lo, hi) = c.feff_range(0);
            for k in 1..200 {
                let f = lo + (hi - lo) * k as f64 / 200.0;
                let dn = c.dn_for(0, f).unwrap();
                let back = c.feff_at(0, dn);
                assert!(
                    (back / f - 1.0).abs() < 1e-9,
                    "{interp:?}: {f:e} -> {dn} -> {back:e}"
                );
            }
            assert_eq!(c.dn_for(0, lo * 0.5), None);
            assert_eq!(c.dn_for(0, hi * 2.0), None);
        }
    }

    #[test]
    fn pchip_stays_monotone_and_within_the_points() {
        let c = curve(EXAMPLE, Interp::Pchip).unwrap();
        let mut prev = 0.0;
        for k in 0..=2550 {
            let f = c.feff_at(0, k as f64 * 0.1);
            assert!(f >= prev, "not monotone at dn {}", k as f64 * 0.1);
            prev = f;
        }
    }

    #[test]
    fn bad_curves_say_what_is_wrong() {
        let head = "# optistim screen calibration v1\n# date: 2026-01-01\n# facility: lab\n# method: m\n# dn_full_scale: 255\n";
        let cases = [
            (format!("{head}dn,feff_w_m2\n0,1\n1,2\n2,3\n"), "at least 4"),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,2\n3,3\n2,4\n"),
                "sort the rows",
            ),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,2\n2,1.5\n3,4\n"),
                "non-monotonic",
            ),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,NaN\n2,3\n3,4\n"),
                "finite",
            ),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,x\n2,3\n3,4\n"),
                "not a number",
            ),
            (
                format!("{head}dn,feff_mw_cm2\n0,1\n1,2\n2,3\n3,4\n"),
                "W/m^2",
            ),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,2,3\n2,3\n3,4\n"),
                "columns",
            ),
            (
                "dn,feff_w_m2\n0,1\n1,2\n2,3\n3,4\n".to_string(),
                "optistim screen calibration v1",
            ),
            (
                head.replace("# facility: lab\n", "") + "dn,feff_w_m2\n0,1\n1,2\n2,3\n3,4\n",
                "facility",
            ),
            (
                head.replace("# dn_full_scale: 255\n", "") + "dn,feff_w_m2\n0,1\n1,2\n2,3\n3,4\n",
                "dn_full_scale",
            ),
            (
                format!("{head}dn,feff_w_m2\n0,1\n1,2\n2,3\n300,4\n"),
                "above dn_full_scale",
            ),
        ];
        for (text, expect) in cases {
            let e = curve(&text, Interp::Linear).unwrap_err().to_string();
            assert!(e.starts_with("t.csv: line"), "{e}");
            assert!(e.contains(expect), "{e:?} lacks {expect:?}");
        }
    }

    #[test]
    fn clipping_is_counted() {
        let c = curve(EXAMPLE, Interp::Linear).unwrap();
        let (lo, hi) = c.feff_range(0);
        let img = [lo * 0.5, lo, 0.5 * (lo + hi), hi, hi * 3.0, f64::NAN, 0.0];
        let mut out = Vec::new();
        let clips = c.invert_image(
            0,
            &img,
            7,
            256,
            super::super::dither::Dither::None,
            &mut out,
        );
        assert_eq!(
            clips,
            ClipCounts {
                black: 1,
                below_dark: 2,
                above_max: 1
            }
        );
        assert_eq!((out[0], out[3], out[4]), (0, 255, 255));
    }

    /// The per-code table's fractional codes match the exact inverse of the PCHIP curve to a
    /// small fraction of a code at 8 and 10 bit.
    #[test]
    fn the_code_table_matches_the_exact_inverse() {
        let c = curve(EXAMPLE, Interp::Pchip).unwrap();
        let (lo, hi) = c.feff_range(0);
        for levels in [256u32, 1024] {
            let inv = c.inverse(0, levels);
            let top = (levels - 1) as f64;
            let mut worst = 0.0f64;
            for k in 0..=2000 {
                let f = lo + (hi - lo) * (k as f64 / 2000.0).powf(3.0);
                let exact = c.dn_for(0, f).unwrap() / c.dn_full_scale * top;
                worst = worst.max((inv.code(f) - exact).abs());
            }
            assert!(worst < 0.01, "{levels} levels: {worst} codes");
        }
    }

    /// Dithering: over a 64 x 64 region of uniform F_eff, the mean F_eff the screen shows is
    /// right to well below half an LSB (the local F_eff step of one level) at 8 and 10 bit;
    /// without dithering the bias reaches almost half an LSB.
    #[test]
    fn dithering_brings_the_region_mean_below_half_an_lsb() {
        use super::super::dither::Dither;
        let c = curve(EXAMPLE, Interp::Pchip).unwrap();
        let (lo, hi) = c.feff_range(0);
        for levels in [256u32, 1024] {
            let top = (levels - 1) as f64;
            let shown = |code: f64| c.feff_at(0, code / top * c.dn_full_scale);
            let (mut worst_plain, mut worst_dither, mut worst_blue) = (0.0f64, 0.0f64, 0.0f64);
            for k in 1..200 {
                let f = lo + (hi - lo) * (k as f64 / 200.0).powf(2.0);
                let img = vec![f; 64 * 64];
                let code = c.dn_for(0, f).unwrap() / c.dn_full_scale * top;
                let lsb = shown(code.floor() + 1.0) - shown(code.floor());
                for (d, worst) in [
                    (Dither::None, &mut worst_plain),
                    (Dither::Ordered, &mut worst_dither),
                    (Dither::BlueNoise, &mut worst_blue),
                ] {
                    let mut out = Vec::new();
                    c.invert_image(0, &img, 64, levels, d, &mut out);
                    let mean = out.iter().map(|&v| shown(v as f64)).sum::<f64>() / out.len() as f64;
                    *worst = worst.max((mean - f).abs() / lsb);
                }
            }
            assert!(
                worst_dither < 0.05,
                "{levels} levels: dithered mean error {worst_dither} LSB"
            );
            assert!(
                worst_blue < 0.05,
                "{levels} levels: blue-noise mean error {worst_blue} LSB"
            );
            assert!(
                worst_plain > 0.3,
                "{levels} levels: the test needs a case plain rounding gets wrong ({worst_plain})"
            );
        }
    }
}
