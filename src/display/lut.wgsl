// The LUT pass: F_eff per screen-region pixel (f32, row-major) -> screen DN code through the inverse
// calibration as a direct table: fractional codes at F = f_lo + (f_hi - f_lo) u^4 for u
// uniform in [0, 1] (dense at the dark end), read with one interpolation, no search. F_eff
// and the table are storage buffers: plain loads, where a software rasteriser's texture
// fetches cost more than the rest of the pass.
// The code is rounded or Bayer-dithered and written as code / top into every colour channel
// of a display target, or as the integer code into the off-screen buffer (compute).
// The same arithmetic as stimulator::calibration::Inverse::apply, to within the table's
// interpolation error (checked when the table is built, display::DirectTable).
//
// A colour screen (stimulator::colour): `feff` holds one plane per camera band; per pixel the
// primaries' F_eff are solved through the cross-talk's (pseudo-)inverse P, and each primary
// goes through its own direct table (the three concatenated in `table`), as
// stimulator::calibration::apply_colour does. Its parameters are in `colour` (below).

struct Params {
    region_origin: vec2<u32>,
    region_size: vec2<u32>,
    // Screen pixels per target pixel: 1 on the stimulator's screen and off-screen, more in a
    // preview window smaller than the screen.
    view_scale: vec2<f32>,
    code_lo: f32,
    code_hi: f32,
    top: f32,
    f_lo: f32,
    f_hi: f32,
    n_table: u32,
    // 1 / (f_hi - f_lo)
    inv_span: f32,
    _reserved: u32,
    // The target's size [px].
    target_px: vec2<u32>,
};

// 0 none, 1 ordered (8 x 8 Bayer), 2 blue noise: a pipeline constant, so that each pipeline
// carries only its own dither (a software adapter pays for branches it does not take).
override dither_kind: u32 = 0u;

@group(0) @binding(0) var<storage, read> feff: array<f32>;
@group(0) @binding(1) var<storage, read> table: array<f32>;
@group(0) @binding(2) var<uniform> p: Params;
// The 64 x 64 blue-noise thresholds, (rank + 0.5) / 4096 (stimulator::dither::blue_noise).
@group(0) @binding(3) var<storage, read> noise: array<f32>;
// A colour screen's parameters, as u32 words (floats by bit pattern):
// [0] bands (0: a grey screen), [1] dither shift, [2..4] unused;
// [4 + 8 c ..]: primary c's code_lo, code_hi, f_lo, f_hi, 1 / (f_hi - f_lo), table offset,
// table entries, unused; [28 + c bands + b]: P[c][b].
@group(0) @binding(4) var<storage, read> colour: array<u32>;

// The 8 x 8 Bayer index at (x, y), from its bits (interleaved x^y and y, reversed): the
// same matrix as stimulator::dither, without a dynamically indexed constant array (which
// software rasterisers copy into every invocation).
fn bayer8(x: u32, y: u32) -> u32 {
    let a = x ^ y;
    return ((a & 1u) << 5u) | ((y & 1u) << 4u) | ((a & 2u) << 2u) | ((y & 2u) << 1u)
        | ((a & 4u) >> 1u) | ((y & 4u) >> 2u);
}

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the target.
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}


// The dither threshold at region pixel q.
fn threshold(q: vec2<u32>) -> f32 {
    var t = 0.5;
    if dither_kind == 1u {
        t = (f32(bayer8(q.x, q.y)) + 0.5) / 64.0;
    } else if dither_kind == 2u {
        t = noise[(q.y % 64u) * 64u + q.x % 64u];
    }
    return t;
}

fn cf(i: u32) -> f32 {
    return bitcast<f32>(colour[i]);
}

// A colour screen's primary: its codes' and F_eff's ranges and its direct table.
struct Primary {
    code_lo: f32,
    code_hi: f32,
    f_lo: f32,
    f_hi: f32,
    inv_span: f32,
    off: u32,
    n: u32,
};

// A colour screen's parameters, read once per invocation.
struct Solve {
    r: Primary,
    g: Primary,
    b: Primary,
    bands: u32,
    shift: u32,
    // P for three bands (column b: band b's weights of R, G, B), read once.
    m: mat3x3<f32>,
};

fn primary(c: u32) -> Primary {
    let base = 4u + 8u * c;
    return Primary(cf(base), cf(base + 1u), cf(base + 2u), cf(base + 3u), cf(base + 4u),
        colour[base + 5u], colour[base + 6u]);
}

fn weights(b: u32, bands: u32) -> vec3<f32> {
    return vec3<f32>(cf(28u + b), cf(28u + bands + b), cf(28u + 2u * bands + b));
}

fn solve() -> Solve {
    let bands = colour[0];
    var m = mat3x3<f32>();
    if bands == 3u {
        m = mat3x3<f32>(weights(0u, 3u), weights(1u, 3u), weights(2u, 3u));
    }
    return Solve(primary(0u), primary(1u), primary(2u), bands, colour[1], m);
}

// A primary's code for its F_eff f with dither threshold t.
fn primary_code(pr: Primary, f: f32, t: f32) -> f32 {
    if f > pr.f_hi {
        return pr.code_hi;
    }
    if !(f >= pr.f_lo) {
        return pr.code_lo;
    }
    let u = sqrt(sqrt(clamp((f - pr.f_lo) * pr.inv_span, 0.0, 1.0)));
    let x = u * f32(pr.n - 1u);
    let k = min(u32(x), pr.n - 2u);
    let code = mix(table[pr.off + k], table[pr.off + k + 1u], x - f32(k));
    return clamp(floor(code + t), pr.code_lo, pr.code_hi);
}

// A colour screen's R, G, B codes at fragment position `pos` (0 outside the image region).
fn screen_rgb(pos: vec4<f32>, s: Solve) -> vec3<f32> {
    let q = vec2<u32>(floor(pos.xy * p.view_scale)) - p.region_origin;
    if q.x >= p.region_size.x || q.y >= p.region_size.y {
        return vec3<f32>(0.0);
    }
    let n = p.region_size.x * p.region_size.y;
    let i = q.y * p.region_size.x + q.x;
    var f = vec3<f32>(0.0);
    if s.bands == 3u {
        f = s.m * vec3<f32>(feff[i], feff[n + i], feff[2u * n + i]);
    } else {
        for (var b = 0u; b < s.bands; b++) {
            f += weights(b, s.bands) * feff[b * n + i];
        }
    }
    let t = threshold(q >> vec2<u32>(s.shift));
    return vec3<f32>(primary_code(s.r, f.x, t), primary_code(s.g, f.y, t),
        primary_code(s.b, f.z, t));
}

// The fractional code showing f (f_lo <= f <= f_hi).
fn code_of(f: f32) -> f32 {
    let u = sqrt(sqrt(clamp((f - p.f_lo) * p.inv_span, 0.0, 1.0)));
    let x = u * f32(p.n_table - 1u);
    let k = min(u32(x), p.n_table - 2u);
    return mix(table[k], table[k + 1u], x - f32(k));
}

// The screen code at fragment position `pos` (0 outside the image region).
fn screen_code(pos: vec4<f32>) -> f32 {
    // Left of or above the region, q wraps around to a large value.
    let q = vec2<u32>(floor(pos.xy * p.view_scale)) - p.region_origin;
    if q.x >= p.region_size.x || q.y >= p.region_size.y {
        return 0.0;
    }
    let f = feff[q.y * p.region_size.x + q.x];
    var c = p.code_lo;
    if f > p.f_hi {
        c = p.code_hi;
    } else if f >= p.f_lo {
        c = clamp(floor(code_of(f) + threshold(q)), p.code_lo, p.code_hi);
    }
    return c;
}

// Display targets (unorm colour): code / top in every colour channel.
@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let v = screen_code(pos) / p.top;
    return vec4<f32>(v, v, v, 1.0);
}

// A colour screen's display targets: each primary's code / top in its channel.
@fragment
fn fs_rgb(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    return vec4<f32>(screen_rgb(pos, solve()) / p.top, 1.0);
}

// The off-screen target: the codes themselves, two 16-bit codes per word (low half first),
// `(target_px.x + 1) / 2` words per row. Each invocation fills two words (four pixels):
// on a software adapter the per-invocation overhead is as large as the LUT itself.
@group(1) @binding(0) var<storage, read_write> codes: array<u32>;

@compute @workgroup_size(64, 1, 1)
fn cs_codes(@builtin(global_invocation_id) id: vec3<u32>) {
    let words = (p.target_px.x + 1u) / 2u;
    if 2u * id.x >= words || id.y >= p.target_px.y {
        return;
    }
    let y = f32(id.y) + 0.5;
    for (var k = 0u; k < 2u; k++) {
        let w = 2u * id.x + k;
        if w < words {
            let x = f32(2u * w) + 0.5;
            let a = u32(screen_code(vec4<f32>(x, y, 0.0, 1.0)));
            let b = u32(screen_code(vec4<f32>(x + 1.0, y, 0.0, 1.0)));
            codes[id.y * words + w] = a | (b << 16u);
        }
    }
}

// A colour screen's off-screen target: one word per pixel, R | G << 10 | B << 20 (codes of
// 10 bit at most), `target_px.x` words per row. Each invocation fills four words: on a
// software adapter the per-invocation overhead (and reading the parameters) is as large as
// the solve itself.
@compute @workgroup_size(64, 1, 1)
fn cs_rgb(@builtin(global_invocation_id) id: vec3<u32>) {
    if 4u * id.x >= p.target_px.x || id.y >= p.target_px.y {
        return;
    }
    let s = solve();
    let y = f32(id.y) + 0.5;
    for (var k = 0u; k < 4u; k++) {
        let x = 4u * id.x + k;
        if x < p.target_px.x {
            let c = vec3<u32>(screen_rgb(vec4<f32>(f32(x) + 0.5, y, 0.0, 1.0), s));
            codes[id.y * p.target_px.x + x] = c.x | (c.y << 10u) | (c.z << 20u);
        }
    }
}
