//! Detector noises (paper Sec. 4.9, Fig. 21), one file per model. Every draw comes from a
//! generator seeded by `(seed, stream, frame, block of 4096 pixels)` and drawn in pixel order,
//! so a frame does not depend on thread scheduling, and fixed-pattern noises (PRNU,
//! dark-signal non-uniformity) stay put from frame to frame (their seed omits the frame).
//! Without fixed patterns, a pixel that collects nothing takes its DN from the exact
//! distribution of readout noise through the ADC, one uniform draw (`detector::DarkDn`).

pub mod dark;
pub mod prnu;
pub mod readout;
pub mod shot;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

pub use dark::DarkCurrent;
pub use prnu::Prnu;
pub use readout::Readout;
pub use shot::Shot;

/// All noise switches and parameters of a camera.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Noise {
    pub shot: Option<Shot>,
    pub prnu: Option<Prnu>,
    pub dark: Option<DarkCurrent>,
    pub readout: Option<Readout>,
}

impl Noise {
    pub fn any(&self) -> bool {
        self.shot.is_some() || self.prnu.is_some() || self.dark.is_some() || self.readout.is_some()
    }
}

/// Which stream a generator belongs to.
#[derive(Clone, Copy)]
#[repr(u64)]
pub enum Stream {
    /// Fixed patterns: PRNU gain, then the pixel's dark current.
    Fixed = 1,
    /// Temporal noises of one frame: shot, dark shot, readout, in that order.
    Temporal = 2,
}

/// SplitMix64 finaliser: decorrelates nearby indices.
#[inline(always)]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A generator for one `(seed, stream, frame, block)` (`block`: a fixed run of pixels);
/// `frame = None` for fixed patterns.
#[inline]
pub fn rng(seed: u64, stream: Stream, frame: Option<u64>, block: u64) -> Pcg64Mcg {
    let f = frame.map_or(0x9e37_79b9_7f4a_7c15, |f| {
        mix(f.wrapping_add(0x632b_e59b_d9b4_e019))
    });
    let s = mix(seed ^ mix(stream as u64) ^ f);
    Pcg64Mcg::seed_from_u64(mix(s ^ block.wrapping_mul(0xd1b5_4a32_d192_ed03)))
}
