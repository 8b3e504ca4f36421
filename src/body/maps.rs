//! Texture maps in the body-fixed frame (paper Sec. 4.4): equirectangular grids, first row at
//! the top latitude, longitude increasing to the right, loaded from TIFF (8/16-bit integer or
//! float32, one band or RGB) through documented encoding fields ([`Encoding`]) and sampled
//! bilinearly with wrap-around in longitude and no seam or singularity at the poles.

use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("{file}: cannot read: {message}")]
    Read { file: String, message: String },
    #[error("{file}: {message}")]
    Format { file: String, message: String },
}

/// How the stored numbers become physical values, applied in this order:
/// 1. integers are divided by their full scale (255, 65535), floats are kept;
/// 2. RGB becomes the mean of its three channels;
/// 3. `v^gamma`;
/// 4. `domain`: `min + (max - min) v`;
/// 5. `scale v + shift`;
/// 6. `mean`: the whole map is rescaled so that its area-weighted mean is this value.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Encoding {
    pub gamma: f64,
    pub domain: Option<[f64; 2]>,
    pub scale: f64,
    pub shift: f64,
    pub mean: Option<f64>,
    /// The grid's extent [deg]: longitude `[west, east]`, latitude `[south, north]`; a map
    /// spanning 360 deg of longitude wraps around.
    pub lon_limits_deg: [f64; 2],
    pub lat_limits_deg: [f64; 2],
}

impl Default for Encoding {
    fn default() -> Self {
        Encoding {
            gamma: 1.0,
            domain: None,
            scale: 1.0,
            shift: 0.0,
            mean: None,
            lon_limits_deg: [-180.0, 180.0],
            lat_limits_deg: [-90.0, 90.0],
        }
    }
}

/// A map of one physical value per texel.
#[derive(Clone, Debug, PartialEq)]
pub struct Map {
    pub file: PathBuf,
    pub width: usize,
    pub height: usize,
    /// Row-major, first row at the north limit.
    pub values: Vec<f32>,
    lon0: f64,
    lat_top: f64,
    dlon: f64,
    dlat: f64,
    wraps: bool,
    /// Whether the first (last) row borders the north (south) pole of a global map.
    north_pole: bool,
    south_pole: bool,
    /// The mean of the first and last rows: the value at the poles of a global map.
    pole_north: f64,
    pole_south: f64,
}

impl Map {
    /// Reads a TIFF and applies `encoding`.
    pub fn load(path: &Path, encoding: &Encoding) -> Result<Map, MapError> {
        let (w, h, channels, raw) = Map::read_samples(path)?;
        let colour = channels.min(3);
        let values: Vec<f64> = raw
            .chunks_exact(channels)
            .map(|px| px[..colour].iter().sum::<f64>() / colour as f64)
            .collect();
        Map::from_values(path, w, h, values, encoding)
    }

    /// Reads an RGB TIFF as three maps, one per channel, each through `encoding` (a normal
    /// map's `2 v - 1` is `scale = 2, shift = -1`).
    pub fn load_rgb(path: &Path, encoding: &Encoding) -> Result<[Map; 3], MapError> {
        let (w, h, channels, raw) = Map::read_samples(path)?;
        if channels < 3 {
            return Err(MapError::Format {
                file: path.display().to_string(),
                message: "one band: three (RGB) expected".into(),
            });
        }
        let band = |k: usize| {
            let v = raw.chunks_exact(channels).map(|px| px[k]).collect();
            Map::from_values(path, w, h, v, encoding)
        };
        Ok([band(0)?, band(1)?, band(2)?])
    }

    /// A TIFF's samples, integers normalised to [0, 1]: `(width, height, channels, samples)`.
    fn read_samples(path: &Path) -> Result<(usize, usize, usize, Vec<f64>), MapError> {
        use tiff::decoder::{Decoder, DecodingResult};
        let file = path.display().to_string();
        let read = |e: &dyn std::fmt::Display| MapError::Read {
            file: file.clone(),
            message: e.to_string(),
        };
        let f = std::fs::File::open(path).map_err(|e| read(&e))?;
        let mut dec = Decoder::new(std::io::BufReader::new(f))
            .map_err(|e| read(&e))?
            .with_limits(tiff::decoder::Limits::unlimited());
        let (w, h) = dec.dimensions().map_err(|e| read(&e))?;
        let channels = match dec.colortype().map_err(|e| read(&e))? {
            tiff::ColorType::Gray(_) => 1,
            tiff::ColorType::RGB(_) => 3,
            tiff::ColorType::RGBA(_) => 4,
            other => {
                return Err(MapError::Format {
                    file,
                    message: format!("{other:?}: one band or RGB expected"),
                });
            }
        };
        let raw: Vec<f64> = match dec.read_image().map_err(|e| read(&e))? {
            DecodingResult::U8(v) => v.iter().map(|&x| x as f64 / 255.0).collect(),
            DecodingResult::U16(v) => v.iter().map(|&x| x as f64 / 65535.0).collect(),
            DecodingResult::F32(v) => v.iter().map(|&x| x as f64).collect(),
            DecodingResult::F64(v) => v,
            _ => {
                return Err(MapError::Format {
                    file,
                    message: "8/16-bit integer or float samples expected".into(),
                });
            }
        };
        let (w, h) = (w as usize, h as usize);
        if raw.len() != w * h * channels {
            return Err(MapError::Format {
                file,
                message: format!("{} samples for {w} x {h} x {channels}", raw.len()),
            });
        }
        Ok((w, h, channels, raw))
    }

    /// A map from decoded values (before the gamma, domain, scale, shift and mean steps).
    pub fn from_values(
        file: &Path,
        width: usize,
        height: usize,
        values: Vec<f64>,
        enc: &Encoding,
    ) -> Result<Map, MapError> {
        let bad = |message: String| MapError::Format {
            file: file.display().to_string(),
            message,
        };
        if width < 2 || height < 2 || values.len() != width * height {
            return Err(bad(format!(
                "a {width} x {height} grid of {} values",
                values.len()
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!(
                "texel {} (row {}, column {}) is not finite",
                i,
                i / width,
                i % width
            )));
        }
        let [west, east] = enc.lon_limits_deg.map(f64::to_radians);
        let [south, north] = enc.lat_limits_deg.map(f64::to_radians);
        if !(east > west && north > south) {
            return Err(bad("longitude or latitude limits out of order".into()));
        }
        let mut v: Vec<f64> = values
            .into_iter()
            .map(|x| {
                let x = if enc.gamma != 1.0 {
                    x.max(0.0).powf(enc.gamma)
                } else {
                    x
                };
                let x = match enc.domain {
                    Some([lo, hi]) => lo + (hi - lo) * x,
                    None => x,
                };
                enc.scale * x + enc.shift
            })
            .collect();
        let dlat = (north - south) / height as f64;
        let area_mean = |v: &[f64]| {
            let (mut s, mut a) = (0.0, 0.0);
            for (r, row) in v.chunks(width).enumerate() {
                let c = (north - (r as f64 + 0.5) * dlat).cos();
                s += c * row.iter().sum::<f64>();
                a += c * width as f64;
            }
            s / a
        };
        if let Some(m) = enc.mean {
            let now = area_mean(&v);
            if now == 0.0 {
                return Err(bad("mean rescaling of a map whose mean is 0".into()));
            }
            v.iter_mut().for_each(|x| *x *= m / now);
        }
        let row_mean = |r: usize| v[r * width..(r + 1) * width].iter().sum::<f64>() / width as f64;
        let wraps = ((east - west) - std::f64::consts::TAU).abs() < 1e-9;
        Ok(Map {
            file: file.to_path_buf(),
            width,
            height,
            pole_north: row_mean(0),
            pole_south: row_mean(height - 1),
            values: v.iter().map(|&x| x as f32).collect(),
            lon0: west,
            lat_top: north,
            dlon: (east - west) / width as f64,
            dlat,
            wraps,
            north_pole: wraps && (north - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
            south_pole: wraps && (south + std::f64::consts::FRAC_PI_2).abs() < 1e-9,
        })
    }

    /// Texel size in longitude and latitude [rad].
    pub fn spacing_rad(&self) -> (f64, f64) {
        (self.dlon, self.dlat)
    }

    /// Whether the map spans all longitudes (and wraps around).
    pub fn wraps(&self) -> bool {
        self.wraps
    }

    /// The values at the north and south poles of a global map that reaches both (the means
    /// of its first and last rows, towards which [`Map::sample`] blends beyond their
    /// centres); `None` for a map that does not.
    pub fn pole_values(&self) -> Option<(f64, f64)> {
        (self.wraps && self.north_pole && self.south_pole)
            .then_some((self.pole_north, self.pole_south))
    }

    /// The latitude of row `r`'s centres [rad].
    pub fn row_lat(&self, r: usize) -> f64 {
        self.lat_top - (r as f64 + 0.5) * self.dlat
    }

    /// Another map on the same grid, with these values (no encoding applied).
    pub fn with_values(&self, values: Vec<f64>) -> Result<Map, MapError> {
        Map::from_values(&self.file, self.width, self.height, values, &self.extent())
    }

    /// The encoding that only places a grid, of any size, on this map's extent.
    fn extent(&self) -> Encoding {
        let west = self.lon0.to_degrees();
        let north = self.lat_top.to_degrees();
        Encoding {
            lon_limits_deg: [west, west + (self.dlon * self.width as f64).to_degrees()],
            lat_limits_deg: [north - (self.dlat * self.height as f64).to_degrees(), north],
            ..Encoding::default()
        }
    }

    /// Longitude and latitude [rad] of the centre of texel `(col, row)` (row 0 at the north
    /// limit), where [`Map::taps`] puts all the weight on it.
    pub fn texel_centre(&self, col: usize, row: usize) -> (f64, f64) {
        (
            self.lon0 + (col as f64 + 0.5) * self.dlon,
            self.lat_top - (row as f64 + 0.5) * self.dlat,
        )
    }

    /// Continuous texel coordinates of `(lon, lat)` [rad]: texel `(col, row)`'s centre at
    /// `(col, row)`, longitude not wrapped.
    #[inline]
    pub fn texel_coords(&self, lon: f64, lat: f64) -> (f64, f64) {
        (
            (lon - self.lon0) / self.dlon - 0.5,
            (self.lat_top - lat) / self.dlat - 0.5,
        )
    }

    /// The area-weighted mean value.
    pub fn mean(&self) -> f64 {
        let (mut s, mut a) = (0.0, 0.0);
        for (r, row) in self.values.chunks(self.width).enumerate() {
            let c = (self.lat_top - (r as f64 + 0.5) * self.dlat).cos();
            s += c * row.iter().map(|&x| x as f64).sum::<f64>();
            a += c * self.width as f64;
        }
        s / a
    }

    /// The value at body longitude and latitude [rad]: bilinear between texel centres, with
    /// wrap-around in longitude for a global map. Between the first (last) row's centres and
    /// the pole it blends towards the row's mean, so that the pole has one value. Outside a
    /// regional map: `None`.
    #[inline]
    pub fn sample(&self, lon: f64, lat: f64) -> Option<f64> {
        self.taps(lon, lat).map(|t| self.at(&t))
    }

    /// Where `(lon, lat)` falls on this map's grid: the texels and weights of [`Map::sample`],
    /// reusable on every map of the same grid ([`Map::same_grid`]) at the cost of one lookup.
    /// Always inlined: a marched shadow ray samples the DEM at every step, and the call was
    /// 8.6 % of a budgeted NRHO frame (row 232); inlined, that frame is about 5 % faster.
    #[inline(always)]
    pub fn taps(&self, lon: f64, lat: f64) -> Option<Taps> {
        let mut x = (lon - self.lon0) / self.dlon - 0.5;
        let w = self.width as f64;
        if self.wraps {
            // One period off at most for longitudes from `atan2`; `rem_euclid` (a libm
            // `fmod`) only for others. Both give the same value.
            if x < 0.0 && x + w >= 0.0 {
                x += w;
            } else if !(0.0..w).contains(&x) {
                x = x.rem_euclid(w);
            }
        } else if x < -0.5 || x > w - 0.5 {
            return None;
        }
        let y = (self.lat_top - lat) / self.dlat - 0.5;
        if y < -0.5 - 1e-12 || y > self.height as f64 - 0.5 + 1e-12 {
            return None;
        }
        let x0 = crate::geometry::floor_i64(x);
        let tx = x - x0 as f64;
        let (c0, c1) = if self.wraps {
            // `x` is in [0, w) but for rounding at the seam; integer remainders (divisions)
            // showed in profiles, so they are kept for that case.
            let c0 = if (0..self.width as i64).contains(&x0) {
                x0 as usize
            } else {
                (x0 as isize).rem_euclid(self.width as isize) as usize
            };
            (c0, if c0 + 1 == self.width { 0 } else { c0 + 1 })
        } else {
            let c0 = (x0.max(0) as usize).min(self.width - 1);
            (c0, (c0 + 1).min(self.width - 1))
        };
        let row = |r: usize, w: f64| {
            let base = (r * self.width) as u32;
            [
                (base + c0 as u32, w * (1.0 - tx)),
                (base + c1 as u32, w * tx),
            ]
        };
        let last = self.height - 1;
        let ([a, b], [c, d], pole) = if y < 0.0 {
            // Between the north pole (or the map's edge) and the first row's centres.
            let t = 2.0 * (y + 0.5); // 0 at the edge, 1 at the centres
            if self.north_pole {
                (row(0, t), row(0, 0.0), (Pole::North, 1.0 - t))
            } else {
                (row(0, 1.0), row(0, 0.0), (Pole::None, 0.0))
            }
        } else if y > last as f64 {
            let t = 2.0 * (y - last as f64); // 0 at the centres, 1 at the edge
            if self.south_pole {
                (row(last, 1.0 - t), row(last, 0.0), (Pole::South, t))
            } else {
                (row(last, 1.0), row(last, 0.0), (Pole::None, 0.0))
            }
        } else {
            let r0 = y as usize; // y >= 0 here: truncation is the floor
            let t = y - r0 as f64;
            (
                row(r0, 1.0 - t),
                row((r0 + 1).min(last), t),
                (Pole::None, 0.0),
            )
        };
        Some(Taps {
            texel: [a.0, b.0, c.0, d.0],
            weight: [a.1, b.1, c.1, d.1],
            pole: pole.0,
            pole_weight: pole.1,
        })
    }

    /// The value at `taps` (from this map or one of the same grid).
    #[inline]
    pub fn at(&self, t: &Taps) -> f64 {
        let mut v = 0.0;
        for k in 0..4 {
            v += t.weight[k] * self.values[t.texel[k] as usize] as f64;
        }
        v + t.pole_weight
            * match t.pole {
                Pole::None => 0.0,
                Pole::North => self.pole_north,
                Pole::South => self.pole_south,
            }
    }

    /// The slope of [`Map::sample`]'s bilinear interpolant at `taps` (from this map or one of
    /// the same grid), per texel: `(d/dx, d/dy)` with `x` along the columns (east) and `y`
    /// along the rows (south). Within a cell the two are exact; on a cell's edge, the cell
    /// the taps chose. `None` between the first (last) row's centres and a pole, where the
    /// map blends towards the pole's value.
    #[inline]
    pub fn gradient(&self, t: &Taps) -> Option<(f64, f64)> {
        if !matches!(t.pole, Pole::None) {
            return None;
        }
        let v = t.texel.map(|k| self.values[k as usize] as f64);
        let [_, b, c, d] = t.weight;
        // The weights are (1-ty)(1-tx), (1-ty) tx, ty (1-tx) and ty tx.
        let (tx, ty) = (b + d, c + d);
        Some((
            (1.0 - ty) * (v[1] - v[0]) + ty * (v[3] - v[2]),
            (1.0 - tx) * (v[2] - v[0]) + tx * (v[3] - v[1]),
        ))
    }

    /// The next coarser level of an area-averaged pyramid: each texel the mean of a 2 x 2
    /// block, its rows weighted by their area (`cos` of their latitude), on the same extent
    /// (with its own pole values: the means of its first and last rows).
    /// `None` when a side is odd or below 4 texels (the pyramid stops there).
    pub fn halved(&self) -> Option<Map> {
        let (w, h) = (self.width, self.height);
        if w % 2 != 0 || h % 2 != 0 || w < 4 || h < 4 {
            return None;
        }
        let (w2, h2) = (w / 2, h / 2);
        let mut v = vec![0.0; w2 * h2];
        for r in 0..h2 {
            let (ca, cb) = (self.row_lat(2 * r).cos(), self.row_lat(2 * r + 1).cos());
            let (ca, cb) = (ca.max(0.0), cb.max(0.0));
            let norm = 2.0 * (ca + cb);
            let (ra, rb) = (2 * r * w, (2 * r + 1) * w);
            for c in 0..w2 {
                let a = self.values[ra + 2 * c] as f64 + self.values[ra + 2 * c + 1] as f64;
                let b = self.values[rb + 2 * c] as f64 + self.values[rb + 2 * c + 1] as f64;
                v[r * w2 + c] = if norm > 0.0 {
                    (ca * a + cb * b) / norm
                } else {
                    0.25 * (a + b)
                };
            }
        }
        Map::from_values(&self.file, w2, h2, v, &self.extent()).ok()
    }

    /// Whether `other` lies on this map's grid (its [`Map::taps`] serve both).
    pub fn same_grid(&self, other: &Map) -> bool {
        (self.width, self.height, self.wraps) == (other.width, other.height, other.wraps)
            && [self.lon0, self.lat_top, self.dlon, self.dlat]
                == [other.lon0, other.lat_top, other.dlon, other.dlat]
    }
}

/// Where a sample falls: four texels (flat indices) and their weights, and the weight of a
/// pole's value.
#[derive(Clone, Copy, Debug)]
pub struct Taps {
    texel: [u32; 4],
    weight: [f64; 4],
    pole: Pole,
    pole_weight: f64,
}

#[derive(Clone, Copy, Debug)]
enum Pole {
    None,
    North,
    South,
}

impl Taps {
    /// The four texels (flat indices) and their weights (without a pole's share).
    pub fn texels(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.texel
            .iter()
            .zip(&self.weight)
            .map(|(&t, &w)| (t as usize, w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    fn ramp(w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> Map {
        let v = (0..w * h).map(|i| f(i % w, i / w)).collect();
        Map::from_values(Path::new("test"), w, h, v, &Encoding::default()).unwrap()
    }

    #[test]
    fn bilinear_between_centres_and_wrap_around_in_longitude() {
        // 8 x 4 map: value = column index.
        let m = ramp(8, 4, |c, _| c as f64);
        let dlon = 2.0 * PI / 8.0;
        // The centre of column 2 and half-way to column 3.
        let lon = |c: f64| -PI + (c + 0.5) * dlon;
        assert!((m.sample(lon(2.0), 0.1).unwrap() - 2.0).abs() < 1e-12);
        assert!((m.sample(lon(2.5), 0.1).unwrap() - 2.5).abs() < 1e-12);
        // Across the seam at 180 deg: half-way between the last column (7) and the first (0).
        assert!((m.sample(PI, 0.1).unwrap() - 3.5).abs() < 1e-12);
        assert!((m.sample(-PI, 0.1).unwrap() - 3.5).abs() < 1e-12);
        // Continuous across the seam.
        let e = 1e-9;
        assert!((m.sample(PI - e, 0.1).unwrap() - m.sample(-PI + e, 0.1).unwrap()).abs() < 1e-6);
    }

    /// The bilinear interpolant's slope is its own: within a cell, the difference quotient
    /// of `sample` over a hundred-thousandth of a texel, per texel (columns east, rows
    /// south); across the seam too; none between the first row's centres and the pole.
    #[test]
    fn the_gradient_is_the_bilinear_interpolants_slope() {
        let m = ramp(16, 8, |c, r| {
            ((c * 7 + r * 3) % 5) as f64 + 0.1 * (c * r) as f64
        });
        let (dlon, dlat) = m.spacing_rad();
        let (e_lon, e_lat) = (1e-5 * dlon, 1e-5 * dlat);
        for (x, y) in [(2.3, 1.6), (7.9, 3.2), (15.7, 2.5), (0.2, 6.4), (10.5, 0.7)] {
            let lon = -PI + (x + 0.5) * dlon;
            let lat = FRAC_PI_2 - (y + 0.5) * dlat;
            let (gx, gy) = m.gradient(&m.taps(lon, lat).unwrap()).unwrap();
            let s = |lon, lat| m.sample(lon, lat).unwrap();
            let fx = (s(lon + e_lon, lat) - s(lon - e_lon, lat)) / (2e-5);
            let fy = (s(lon, lat - e_lat) - s(lon, lat + e_lat)) / (2e-5);
            assert!(
                (gx - fx).abs() < 1e-6 && (gy - fy).abs() < 1e-6,
                "{x} {y}: {gx} {fx} {gy} {fy}"
            );
        }
        let near_pole = m.taps(0.3, FRAC_PI_2 - 0.2 * dlat).unwrap();
        assert!(m.gradient(&near_pole).is_none());
    }

    /// A halved level is the area-weighted mean of each 2 x 2 block, on the same extent: its
    /// area-weighted mean is the map's (a constant stays constant), and it samples the block's
    /// mean at the block's centre.
    #[test]
    fn a_halved_level_keeps_the_area_mean_and_the_extent() {
        let m = ramp(16, 8, |c, r| ((c * 7 + r * 3) % 5) as f64);
        let h = m.halved().unwrap();
        assert_eq!((h.width, h.height), (8, 4));
        assert!(
            (h.mean() - m.mean()).abs() < 1e-6,
            "{} {}",
            h.mean(),
            m.mean()
        );
        let (lon, lat) = h.texel_centre(3, 1);
        let rows = [2usize, 3];
        let (mut s, mut a) = (0.0, 0.0);
        for r in rows {
            let c = m.row_lat(r).cos();
            for col in [6usize, 7] {
                s += c * m.values[r * 16 + col] as f64;
                a += c;
            }
        }
        assert!((h.sample(lon, lat).unwrap() - s / a).abs() < 1e-6);
        let flat = ramp(8, 4, |_, _| 0.3).halved().unwrap();
        assert!(flat.values.iter().all(|&v| (v - 0.3).abs() < 1e-7));
        assert!(ramp(6, 4, |_, _| 1.0).halved().is_some());
        assert!(ramp(6, 4, |_, _| 1.0).halved().unwrap().halved().is_none());
    }

    #[test]
    fn the_poles_have_one_value_whatever_the_longitude() {
        let m = ramp(8, 4, |c, r| (c * 10 + r) as f64);
        let north: Vec<f64> = (0..16)
            .map(|k| m.sample(k as f64 * 0.4, FRAC_PI_2).unwrap())
            .collect();
        assert!(
            north.iter().all(|v| (v - north[0]).abs() < 1e-12),
            "{north:?}"
        );
        let south = m.sample(1.0, -FRAC_PI_2).unwrap();
        assert!((south - m.sample(-2.0, -FRAC_PI_2).unwrap()).abs() < 1e-12);
        // Continuous from the first row's centres to the pole.
        let first_row_lat = FRAC_PI_2 - 0.5 * PI / 4.0;
        let just_below = m.sample(0.3, first_row_lat - 1e-9).unwrap();
        let just_above = m.sample(0.3, first_row_lat + 1e-9).unwrap();
        assert!((just_below - just_above).abs() < 1e-6);
    }

    #[test]
    fn encoding_steps_apply_in_order_and_mean_rescaling_hits_its_target() {
        let enc = Encoding {
            gamma: 2.0,
            domain: Some([0.1, 0.5]),
            scale: 2.0,
            shift: 1.0,
            ..Default::default()
        };
        let m = Map::from_values(Path::new("t"), 2, 2, vec![0.5; 4], &enc).unwrap();
        // 0.5^2 = 0.25 -> 0.1 + 0.4 * 0.25 = 0.2 -> 2 * 0.2 + 1 = 1.4
        assert!((m.values[0] as f64 - 1.4).abs() < 1e-6);
        let enc = Encoding {
            mean: Some(0.12),
            ..Default::default()
        };
        let m = Map::from_values(
            Path::new("t"),
            4,
            4,
            (0..16).map(|i| i as f64 + 1.0).collect(),
            &enc,
        )
        .unwrap();
        assert!((m.mean() - 0.12).abs() < 1e-7);
    }

    #[test]
    fn regional_maps_do_not_wrap_and_say_where_they_end() {
        let enc = Encoding {
            lon_limits_deg: [10.0, 20.0],
            lat_limits_deg: [-5.0, 5.0],
            ..Default::default()
        };
        let m = Map::from_values(Path::new("t"), 4, 4, vec![1.0; 16], &enc).unwrap();
        assert_eq!(m.sample(15f64.to_radians(), 0.0), Some(1.0));
        assert_eq!(m.sample(25f64.to_radians(), 0.0), None);
        assert_eq!(m.sample(15f64.to_radians(), 6f64.to_radians()), None);
    }

    /// The Moon's albedo map of ../shared (2048 x 1024 RGB, LZW) decodes with the ABRAM
    /// encoding (gamma 2.8, domain [0.12, 0.48]) into plausible values.
    #[test]
    fn the_shared_lunar_albedo_map_loads() {
        let p = Path::new("../shared/data/moon/lroc_color_poles_2k.tif");
        let enc = Encoding {
            gamma: 2.8,
            domain: Some([0.12, 0.48]),
            ..Default::default()
        };
        let m = Map::load(p, &enc).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((m.width, m.height), (2048, 1024));
        let mean = m.mean();
        assert!(mean > 0.12 && mean < 0.3, "{mean}");
        let dem = Map::load(
            Path::new("../shared/data/moon/ldem_4.tif"),
            &Encoding::default(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((dem.width, dem.height), (1440, 720));
        let (lo, hi) = dem
            .values
            .iter()
            .fold((f32::MAX, f32::MIN), |a, &v| (a.0.min(v), a.1.max(v)));
        assert!(
            lo > -10.0 && lo < -8.0 && hi > 10.0 && hi < 11.0,
            "{lo} .. {hi} km"
        );
    }
}
