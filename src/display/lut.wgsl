// The LUT pass: F_eff per camera pixel (R32Float, the screen region) -> screen DN code through
// the inverse calibration table (F_eff at every quarter code, increasing; a width x 1 2D
// texture, since a 1D texture read back as 0 on the GL backend), rounded or Bayer-dithered,
// written as code / top into every colour channel. The same arithmetic as
// stimulator::calibration::Inverse::apply.

struct Params {
    region_origin: vec2<u32>,
    region_size: vec2<u32>,
    code_lo: f32,
    top: f32,
    f_lo: f32,
    f_hi: f32,
    n_table: u32,
    substeps: f32,
    dither: u32,
    code_hi: f32,
};

@group(0) @binding(0) var feff: texture_2d<f32>;
@group(0) @binding(1) var table: texture_2d<f32>;
@group(0) @binding(2) var<uniform> p: Params;

const BAYER8 = array<u32, 64>(
    0u, 32u, 8u, 40u, 2u, 34u, 10u, 42u,
    48u, 16u, 56u, 24u, 50u, 18u, 58u, 26u,
    12u, 44u, 4u, 36u, 14u, 46u, 6u, 38u,
    60u, 28u, 52u, 20u, 62u, 30u, 54u, 22u,
    3u, 35u, 11u, 43u, 1u, 33u, 9u, 41u,
    51u, 19u, 59u, 27u, 49u, 17u, 57u, 25u,
    15u, 47u, 7u, 39u, 13u, 45u, 5u, 37u,
    63u, 31u, 55u, 23u, 61u, 29u, 53u, 21u,
);

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the target.
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

fn entry(k: u32) -> f32 {
    return textureLoad(table, vec2<i32>(i32(k), 0), 0).r;
}

// The fractional code showing f: first table entry above f by bisection, then linear
// interpolation inside the quarter code.
fn code_of(f: f32) -> f32 {
    var lo = 0u;
    var hi = p.n_table;
    loop {
        if lo >= hi { break; }
        let mid = (lo + hi) / 2u;
        if entry(mid) <= f { lo = mid + 1u; } else { hi = mid; }
    }
    let k = lo;
    if k == 0u { return p.code_lo; }
    if k == p.n_table { return p.code_hi; }
    let a = entry(k - 1u);
    let b = entry(k);
    return p.code_lo + (f32(k - 1u) + (f - a) / (b - a)) / p.substeps;
}

@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let px = vec2<u32>(floor(pos.xy));
    if any(px < p.region_origin) || any(px >= p.region_origin + p.region_size) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let q = px - p.region_origin;
    let f = textureLoad(feff, vec2<i32>(q), 0).r;
    var c = p.code_lo;
    if f > p.f_hi {
        c = p.code_hi;
    } else if f >= p.f_lo {
        let x = code_of(f);
        var t = 0.5;
        if p.dither == 1u {
            t = (f32(BAYER8[(q.y & 7u) * 8u + (q.x & 7u)]) + 0.5) / 64.0;
        }
        c = clamp(floor(x + t), p.code_lo, p.code_hi);
    }
    let v = c / p.top;
    return vec4<f32>(v, v, v, 1.0);
}
