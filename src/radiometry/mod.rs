//! Radiometry: the Sun's spectrum, tabulated spectral curves and the band integrals that turn
//! the geometric power-to-radiance coefficient (P/L) into power and signal.
//!
//! Symbols (paper `physically-based-rendering-of-celestial-bodies.md`, Table 2):
//! `L_e,lambda` spectral radiance of the Sun [W m^-2 sr^-1 m^-1], `A_sun` its frontal area [m^2],
//! `F` flux density [W m^-2], `QE` quantum efficiency [e-/photon], `T` optics transmittance [-].

use thiserror::Error;

/// Planck constant [J s].
pub const H: f64 = 6.626_070_15e-34;
/// Speed of light [m/s].
pub const C: f64 = 299_792_458.0;
/// Boltzmann constant [J/K].
pub const K_B: f64 = 1.380_649e-23;
/// Stefan-Boltzmann constant [W m^-2 K^-4].
pub const SIGMA: f64 = 5.670_374_419e-8;
/// Astronomical unit [m].
pub const AU: f64 = 1.495_978_707e11;

#[derive(Debug, Error, PartialEq)]
pub enum TableError {
    #[error("needs at least 2 points, got {0}")]
    TooFewPoints(usize),
    #[error("wavelength and value columns differ in length ({0} vs {1})")]
    LengthMismatch(usize, usize),
    #[error("value at index {index} is not finite ({value})")]
    NotFinite { index: usize, value: f64 },
    #[error("wavelengths must increase strictly (index {index}: {value:.6e} m after {prev:.6e} m)")]
    NotIncreasing { index: usize, value: f64, prev: f64 },
    #[error("value at index {index} is {value}, allowed range is [{min}, {max}]")]
    OutOfRange {
        index: usize,
        value: f64,
        min: f64,
        max: f64,
    },
}

/// A curve tabulated over wavelength, linearly interpolated, zero outside its range.
#[derive(Clone, Debug, PartialEq)]
pub struct SpectralTable {
    wavelength_m: Vec<f64>,
    value: Vec<f64>,
}

impl SpectralTable {
    /// Validates and builds a table; `range` bounds the values (e.g. `[0, 1]` for QE).
    pub fn new(
        wavelength_m: Vec<f64>,
        value: Vec<f64>,
        range: (f64, f64),
    ) -> Result<Self, TableError> {
        if wavelength_m.len() != value.len() {
            return Err(TableError::LengthMismatch(wavelength_m.len(), value.len()));
        }
        if wavelength_m.len() < 2 {
            return Err(TableError::TooFewPoints(wavelength_m.len()));
        }
        for (i, (&w, &v)) in wavelength_m.iter().zip(&value).enumerate() {
            if !w.is_finite() || w <= 0.0 {
                return Err(TableError::NotFinite { index: i, value: w });
            }
            if !v.is_finite() {
                return Err(TableError::NotFinite { index: i, value: v });
            }
            if v < range.0 || v > range.1 {
                return Err(TableError::OutOfRange {
                    index: i,
                    value: v,
                    min: range.0,
                    max: range.1,
                });
            }
            if i > 0 && w <= wavelength_m[i - 1] {
                return Err(TableError::NotIncreasing {
                    index: i,
                    value: w,
                    prev: wavelength_m[i - 1],
                });
            }
        }
        Ok(SpectralTable {
            wavelength_m,
            value,
        })
    }

    /// A flat curve of `value` over `[lo, hi]`.
    pub fn flat(lo_m: f64, hi_m: f64, value: f64) -> Self {
        SpectralTable {
            wavelength_m: vec![lo_m, hi_m],
            value: vec![value, value],
        }
    }

    pub fn range_m(&self) -> (f64, f64) {
        (self.wavelength_m[0], *self.wavelength_m.last().unwrap())
    }

    pub fn wavelengths_m(&self) -> &[f64] {
        &self.wavelength_m
    }

    /// Linear interpolation, the end values held outside the tabulated range (for a
    /// reflectance spectrum, which does not drop to nothing past its last measurement).
    pub fn at_clamped(&self, wavelength_m: f64) -> f64 {
        let (lo, hi) = self.range_m();
        self.at(wavelength_m.clamp(lo, hi))
    }

    /// Linear interpolation, zero outside the tabulated range.
    pub fn at(&self, wavelength_m: f64) -> f64 {
        let w = &self.wavelength_m;
        if wavelength_m < w[0] || wavelength_m > *w.last().unwrap() {
            return 0.0;
        }
        let i = w
            .partition_point(|&x| x <= wavelength_m)
            .clamp(1, w.len() - 1);
        let t = (wavelength_m - w[i - 1]) / (w[i] - w[i - 1]);
        self.value[i - 1] + t * (self.value[i] - self.value[i - 1])
    }
}

/// Spectral radiance of a black body, Eq. 6 [W m^-2 sr^-1 m^-1].
pub fn planck_radiance(wavelength_m: f64, temperature_k: f64) -> f64 {
    let l = wavelength_m;
    let x = H * C / (l * K_B * temperature_k);
    2.0 * H * C * C / (l.powi(5) * x.exp_m1())
}

/// The Sun as a point-wise Lambertian emitter (Eq. 5): spectral radiance `L_e,lambda` times its
/// frontal area `A_sun`.
#[derive(Clone, Debug, PartialEq)]
pub enum SunSpectrum {
    /// Black body of temperature T and radius R (Eq. 6); `scale` multiplies the spectrum
    /// (1 for the pure black body, or set so the total irradiance at 1 AU matches a measured
    /// value such as 1361 W/m^2).
    BlackBody {
        temperature_k: f64,
        radius_m: f64,
        scale: f64,
    },
    /// Spectral irradiance tabulated at `distance_m` from the Sun [W m^-2 m^-1]; converted to
    /// an equivalent radiance over a disk of `radius_m`.
    Tabulated {
        irradiance: SpectralTable,
        distance_m: f64,
        radius_m: f64,
    },
}

impl SunSpectrum {
    /// Frontal area `A_sun = pi R_sun^2` [m^2].
    pub fn area_m2(&self) -> f64 {
        let r = match self {
            SunSpectrum::BlackBody { radius_m, .. } | SunSpectrum::Tabulated { radius_m, .. } => {
                *radius_m
            }
        };
        std::f64::consts::PI * r * r
    }

    /// Spectral radiance `L_e,lambda` [W m^-2 sr^-1 m^-1].
    pub fn radiance(&self, wavelength_m: f64) -> f64 {
        match self {
            SunSpectrum::BlackBody {
                temperature_k,
                scale,
                ..
            } => scale * planck_radiance(wavelength_m, *temperature_k),
            SunSpectrum::Tabulated {
                irradiance,
                distance_m,
                ..
            } => irradiance.at(wavelength_m) * distance_m * distance_m / self.area_m2(),
        }
    }

    /// `integral of L_e,lambda d lambda` over `band` (whole spectrum if `None`) [W m^-2 sr^-1].
    /// Multiplied by (P/L) this is the collected power (Eqs. 9, 56).
    pub fn radiance_integral(&self, band_m: Option<(f64, f64)>) -> f64 {
        match (self, band_m) {
            (
                SunSpectrum::BlackBody {
                    temperature_k,
                    scale,
                    ..
                },
                None,
            ) => scale * SIGMA * temperature_k.powi(4) / std::f64::consts::PI,
            (SunSpectrum::Tabulated { irradiance, .. }, None) => {
                let (lo, hi) = irradiance.range_m();
                integrate(|l| self.radiance(l), lo, hi, irradiance.wavelengths_m())
            }
            (_, Some((lo, hi))) => integrate(|l| self.radiance(l), lo, hi, &[]),
        }
    }

    /// Total flux density at `distance_m` from the Sun [W/m^2] (Eq. 5 integrated).
    pub fn irradiance_at(&self, distance_m: f64) -> f64 {
        self.area_m2() * self.radiance_integral(None) / (distance_m * distance_m)
    }

    /// The signal factor of Eq. 10 / Eq. 45,
    /// `integral over the band of QE T lambda/(h c) L_e,lambda d lambda` [e- s^-1 m^-2 sr^-1]:
    /// multiplied by (P/L) [sr m^2] it gives the signal S [e-/s].
    pub fn signal_integral(&self, qe: &SpectralTable, transmittance: &SpectralTable) -> f64 {
        self.reflected_signal_integral(qe, transmittance, None)
    }

    /// [`SunSpectrum::signal_integral`] for light reflected by a surface of spectral shape
    /// `reflectance` (grey when `None`): the band's factor of Eq. 45 with the BRDF's spectral
    /// dependence inside the integral, `integral of QE T lambda/(h c) r(lambda) L_e,lambda`,
    /// `r` relative to the wavelength the albedo holds at ([`Reflectance::relative`]).
    pub fn reflected_signal_integral(
        &self,
        qe: &SpectralTable,
        transmittance: &SpectralTable,
        reflectance: Option<&Reflectance>,
    ) -> f64 {
        let (lo, hi) = qe.range_m();
        let mut knots: Vec<f64> = qe.wavelengths_m().to_vec();
        knots.extend_from_slice(transmittance.wavelengths_m());
        if let Some(r) = reflectance {
            knots.extend_from_slice(r.table.wavelengths_m());
        }
        let r = |l: f64| reflectance.map_or(1.0, |r| r.relative(l));
        integrate(
            |l| qe.at(l) * transmittance.at(l) * l / (H * C) * self.radiance(l) * r(l),
            lo,
            hi,
            &knots,
        )
    }

    /// The Sun's radiance integrated over `band_m` (the whole spectrum when `None`) after
    /// reflection by a surface of spectral shape `reflectance` [W m^-2 sr^-1]: multiplied by
    /// (P/L) it is the collected power (Eq. 9).
    pub fn reflected_radiance_integral(
        &self,
        band_m: Option<(f64, f64)>,
        reflectance: Option<&Reflectance>,
    ) -> f64 {
        let Some(r) = reflectance else {
            return self.radiance_integral(band_m);
        };
        let mut knots = r.table.wavelengths_m().to_vec();
        if let SunSpectrum::Tabulated { irradiance, .. } = self {
            knots.extend_from_slice(irradiance.wavelengths_m());
        }
        let reflected =
            |lo: f64, hi: f64| integrate(|l| self.radiance(l) * r.relative(l), lo, hi, &knots);
        if let Some((lo, hi)) = band_m {
            return reflected(lo, hi);
        }
        // The whole spectrum: numerically over the reflectance table, and beyond it (where
        // the table's end values hold) the Sun's own integral times those values.
        let (t_lo, t_hi) = r.table.range_m();
        let start = match self {
            SunSpectrum::Tabulated { irradiance, .. } => irradiance.range_m().0,
            SunSpectrum::BlackBody { .. } => 1e-9,
        };
        let upto = |l: f64| {
            if l > start {
                self.radiance_integral(Some((start, l)))
            } else {
                0.0
            }
        };
        let above = (self.radiance_integral(None) - upto(t_hi)).max(0.0);
        upto(t_lo) * r.relative(t_lo) + reflected(t_lo, t_hi) + above * r.relative(t_hi)
    }
}

/// A surface's spectral reflectance shape: the albedo (or the albedo map) holds at
/// `reference_m`, and at any other wavelength is multiplied by `table(lambda) /
/// table(reference)` (the table's end values held beyond its range). It moves the BRDF's
/// spectral dependence, which the (P/L) of Eq. 9 leaves out, into each band's integral
/// (Eq. 45 per band), so one render serves every band.
#[derive(Clone, Debug, PartialEq)]
pub struct Reflectance {
    /// Where the data came from, for headers and notes.
    pub name: String,
    pub table: SpectralTable,
    pub reference_m: f64,
}

impl Reflectance {
    /// Builds the shape; the table must be positive at `reference_m`.
    pub fn new(name: &str, table: SpectralTable, reference_m: f64) -> Result<Self, TableError> {
        let at = table.at_clamped(reference_m);
        if !(reference_m.is_finite() && reference_m > 0.0 && at > 0.0) {
            return Err(TableError::OutOfRange {
                index: 0,
                value: at,
                min: f64::MIN_POSITIVE,
                max: f64::INFINITY,
            });
        }
        Ok(Reflectance {
            name: name.into(),
            table,
            reference_m,
        })
    }

    /// `r(lambda) / r(reference)` [-].
    #[inline]
    pub fn relative(&self, wavelength_m: f64) -> f64 {
        self.table.at_clamped(wavelength_m) / self.table.at_clamped(self.reference_m)
    }

    /// The average Moon's spectrum: its equivalent albedo at 6 deg phase from Earth-based
    /// absolute photometry, 350-2500 nm (Velikodsky, Opanasenko, Akimov et al. 2011, "New
    /// Earth-based absolute photometry of the Moon", Icarus 214, 30-45: the "average Moon"
    /// column, every point to 1100 nm, then every 100 nm). Only its shape is used.
    pub fn moon(reference_m: f64) -> Result<Self, TableError> {
        const NM: [f64; 41] = [
            350., 373., 397., 420., 443., 467., 490., 513., 537., 560., 583., 607., 630., 653.,
            677., 700., 723., 747., 770., 793., 800., 850., 900., 950., 1000., 1050., 1100., 1200.,
            1300., 1400., 1500., 1600., 1700., 1800., 1900., 2000., 2100., 2200., 2300., 2400.,
            2500.,
        ];
        const A_EQ: [f64; 41] = [
            0.0728, 0.0803, 0.0873, 0.0931, 0.0988, 0.1049, 0.1106, 0.1162, 0.1219, 0.1275, 0.1322,
            0.1366, 0.1411, 0.1452, 0.1492, 0.1531, 0.1569, 0.1602, 0.1629, 0.1648, 0.1660, 0.1688,
            0.1718, 0.1764, 0.1826, 0.1900, 0.1981, 0.2136, 0.2273, 0.2390, 0.2523, 0.2613, 0.2686,
            0.2745, 0.2810, 0.2880, 0.2964, 0.3068, 0.3192, 0.3342, 0.3466,
        ];
        let table = SpectralTable::new(
            NM.iter().map(|n| n * 1e-9).collect(),
            A_EQ.to_vec(),
            (0.0, 1.0),
        )?;
        Reflectance::new("moon (Velikodsky et al. 2011)", table, reference_m)
    }
}

/// `max over lambda of QE T lambda` [m], the normaliser of Eqs. 58-60.
pub fn max_qe_t_lambda(qe: &SpectralTable, transmittance: &SpectralTable) -> f64 {
    let (lo, hi) = qe.range_m();
    let n = 4000;
    (0..=n)
        .map(|i| lo + (hi - lo) * i as f64 / n as f64)
        .chain(qe.wavelengths_m().iter().copied())
        .map(|l| qe.at(l) * transmittance.at(l) * l)
        .fold(0.0, f64::max)
}

/// Integrates a piecewise-smooth function over `[lo, hi]`: the interval is split at the
/// `knots` (where tabulated curves have kinks) and each piece is integrated with 16-point
/// Gauss-Legendre on sub-intervals of at most 5 nm (black-body and linear pieces integrate to
/// better than 1e-12 relative).
pub fn integrate(f: impl Fn(f64) -> f64, lo: f64, hi: f64, knots: &[f64]) -> f64 {
    let mut edges: Vec<f64> = knots
        .iter()
        .copied()
        .filter(|&k| k > lo && k < hi)
        .collect();
    edges.push(lo);
    edges.push(hi);
    edges.sort_by(f64::total_cmp);
    edges.dedup();
    let mut sum = 0.0;
    for w in edges.windows(2) {
        let (a, b) = (w[0], w[1]);
        let n = ((b - a) / 5e-9).ceil().max(1.0) as usize;
        let h = (b - a) / n as f64;
        for k in 0..n {
            sum += gauss_legendre_16(&f, a + k as f64 * h, a + (k + 1) as f64 * h);
        }
    }
    sum
}

/// 16-point Gauss-Legendre nodes and weights on [-1, 1] (positive half).
const GL16_X: [f64; 8] = [
    0.0950125098376374,
    0.2816035507792589,
    0.4580167776572274,
    0.6178762444026438,
    0.755404408355003,
    0.8656312023878318,
    0.9445750230732326,
    0.9894009349916499,
];
const GL16_W: [f64; 8] = [
    0.1894506104550685,
    0.1826034150449236,
    0.1691565193950025,
    0.1495959888165767,
    0.1246289712555339,
    0.0951585116824928,
    0.0622535239386479,
    0.0271524594117541,
];

/// 16-point Gauss-Legendre on `[a, b]`.
pub fn gauss_legendre_16(f: &impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let m = 0.5 * (a + b);
    let r = 0.5 * (b - a);
    let mut s = 0.0;
    for k in 0..8 {
        s += GL16_W[k] * (f(m - r * GL16_X[k]) + f(m + r * GL16_X[k]));
    }
    s * r
}

/// Gauss-Legendre nodes and weights of order `n` on [-1, 1] (Newton on P_n).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        loop {
            let (mut p0, mut p1) = (1.0, 0.0);
            for j in 0..n {
                let p2 = p1;
                p1 = p0;
                p0 = ((2 * j + 1) as f64 * z * p1 - j as f64 * p2) / (j + 1) as f64;
            }
            let dp = n as f64 * (z * p0 - p1) / (z * z - 1.0);
            let dz = p0 / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                x[i] = z;
                w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
                break;
            }
        }
    }
    (x, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn black_body_sun_gives_about_1370_at_1au() {
        let sun = SunSpectrum::BlackBody {
            temperature_k: 5782.0,
            radius_m: 6.95e8,
            scale: 1.0,
        };
        let f = sun.irradiance_at(AU);
        assert!((f - 1370.0).abs() < 3.0, "{f}");
        // Numerical spectral integral agrees with Stefan-Boltzmann.
        let num = sun.radiance_integral(Some((50e-9, 200e-6)));
        let ana = sun.radiance_integral(None);
        assert!((num / ana - 1.0).abs() < 1e-4, "{num} {ana}");
    }

    #[test]
    fn table_rejects_bad_input() {
        assert!(matches!(
            SpectralTable::new(vec![1.0], vec![0.5], (0.0, 1.0)),
            Err(TableError::TooFewPoints(1))
        ));
        assert!(matches!(
            SpectralTable::new(vec![2.0, 1.0], vec![0.5, 0.5], (0.0, 1.0)),
            Err(TableError::NotIncreasing { .. })
        ));
        assert!(matches!(
            SpectralTable::new(vec![1.0, 2.0], vec![0.5, 1.5], (0.0, 1.0)),
            Err(TableError::OutOfRange { .. })
        ));
        assert!(matches!(
            SpectralTable::new(vec![1.0, 2.0], vec![f64::NAN, 0.5], (0.0, 1.0)),
            Err(TableError::NotFinite { .. })
        ));
    }

    /// The reflected whole-spectrum integral: a flat shape gives the Sun's own; a sloped one
    /// the brute-force integral over the whole spectrum with the table's ends held.
    #[test]
    fn reflected_radiance_holds_the_tables_ends_beyond_it() {
        let sun = SunSpectrum::BlackBody {
            temperature_k: 5782.0,
            radius_m: 6.957e8,
            scale: 1.0,
        };
        let flat = SpectralTable::new(vec![400e-9, 1000e-9], vec![0.3, 0.3], (0.0, 1.0)).unwrap();
        let r = Reflectance::new("flat", flat, 550e-9).unwrap();
        let whole = sun.radiance_integral(None);
        let got = sun.reflected_radiance_integral(None, Some(&r));
        assert!((got / whole - 1.0).abs() < 1e-6, "{got} {whole}");
        let slope = SpectralTable::new(vec![400e-9, 1000e-9], vec![0.1, 0.3], (0.0, 1.0)).unwrap();
        let r = Reflectance::new("slope", slope, 700e-9).unwrap();
        let got = sun.reflected_radiance_integral(None, Some(&r));
        let brute = integrate(
            |l| sun.radiance(l) * r.relative(l),
            50e-9,
            200e-6,
            &[400e-9, 1e-6],
        );
        assert!((got / brute - 1.0).abs() < 1e-4, "{got} {brute}");
        // Over a band it is the band's integral.
        let band = sun.reflected_radiance_integral(Some((500e-9, 600e-9)), Some(&r));
        let want = integrate(|l| sun.radiance(l) * r.relative(l), 500e-9, 600e-9, &[]);
        assert!((band / want - 1.0).abs() < 1e-12);
    }

    #[test]
    fn gauss_legendre_integrates_polynomials() {
        let (x, w) = gauss_legendre(10);
        let s: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(18)).sum();
        assert!((s - 2.0 / 19.0).abs() < 1e-14);
    }
}
