//! A sphere of uniform surface properties (paper Sec. 4).

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Radius [m].
    pub radius_m: f64,
}
