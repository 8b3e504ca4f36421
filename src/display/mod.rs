//! The presenter: one wgpu device and queue, and the LUT pass that turns the screen region's
//! F_eff into screen DN codes on the GPU (`lut.wgsl`: the inverse calibration as a direct
//! table, dithering as [`crate::stimulator::calibration::Inverse::apply`], in f32).
//!
//! One shader function (`screen_code`), the same inputs and bindings, serve three kinds of
//! target: an off-screen buffer of codes read back to memory ([`Presenter::draw_offscreen`];
//! tests, headless runs; a compute pass, since a software rasteriser spends more on
//! rasterising than on the LUT), and through a render pass the windows of [`window`]: a
//! borderless fullscreen window on the stimulator's monitor and the operator's preview.
//! The dither kind is a pipeline constant (one pipeline per target format and dither).
//! A colour screen ([`Presenter::set_colour`]) takes one F_eff plane per camera band and
//! solves each pixel for its R, G, B codes in the same pass (`screen_rgb`), as
//! [`crate::stimulator::calibration::apply_colour`] does on the CPU.
//! The presenter never runs on the async runtime; `pollster` blocks on wgpu's futures.

pub mod window;

use crate::stimulator::calibration::Inverse;
use crate::stimulator::colour::{Crosstalk, PRIMARIES};
use crate::stimulator::dither::Dither;
use crate::stimulator::{Drive, StimulatorConfig};
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum DisplayError {
    #[error(
        "no wgpu adapter: {0} (on a machine without a GPU install Mesa's software Vulkan \
         driver: apt-get install mesa-vulkan-drivers libvulkan1)"
    )]
    NoAdapter(String),
    #[error("wgpu device: {0}")]
    Device(String),
    #[error("read-back of the off-screen target failed: {0}")]
    Readback(String),
    #[error("F_eff region has {got} values, the region {want}")]
    RegionSize { got: usize, want: usize },
    #[error("no calibration uploaded yet (Presenter::set_inverse)")]
    NoCalibration,
    #[error("no frame uploaded yet (Presenter::upload)")]
    NoFrame,
    #[error(
        "the inverse calibration cannot be tabulated to {max_code_error} code: {got:.3} code \
         at {entries} entries (a curve with a near-vertical step?)"
    )]
    Table {
        got: f64,
        entries: usize,
        max_code_error: f64,
    },
    #[error("window: {0}")]
    Window(String),
    #[error("monitor {wanted} not found; monitors: {available} (name them by index or by name)")]
    NoMonitor { wanted: String, available: String },
    #[error(
        "monitor {monitor} is {got:?} px but the [stimulator] screen is {want:?} px: 1:1 \
         pixels need the screen_resolution_px of the monitor"
    )]
    MonitorSize {
        monitor: String,
        got: [u32; 2],
        want: [usize; 2],
    },
    #[error(
        "the window's surface offers no {bits}-bit format (offers {offered}); set \
         screen_bit_depth to match the display"
    )]
    SurfaceFormat { bits: u32, offered: String },
}

/// Time per presenter stage [ms]. `readback` includes waiting for the GPU to finish the pass;
/// on a window target it is the time to hand the frame to the compositor.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PresentTimings {
    pub upload: f64,
    pub lut_pass: f64,
    pub readback: f64,
}

impl PresentTimings {
    pub fn total(&self) -> f64 {
        self.upload + self.lut_pass + self.readback
    }
}

/// The largest interpolation error of the direct table, in codes, that
/// [`DirectTable::build`] accepts: far below the ±1 LSB the pass is held to.
pub const MAX_TABLE_CODE_ERROR: f64 = 0.02;
/// The direct table's first size; it doubles up to 16 times this.
const TABLE_ENTRIES: usize = 4096;

/// The inverse calibration tabulated for the GPU: the fractional code at
/// `F = f_lo + (f_hi - f_lo) u^4`, `u = i / (n - 1)`. The fourth power puts most entries at the
/// dark end, where a gamma-like screen's code changes fastest with F_eff.
#[derive(Clone, Debug)]
pub struct DirectTable {
    pub codes: Vec<f32>,
    /// The largest difference between the interpolated table and [`Inverse::code`], sampled
    /// at three points inside every interval [codes].
    pub max_code_error: f64,
}

impl DirectTable {
    /// Builds the table from 4096 entries up, doubling until the interpolation error is below
    /// [`MAX_TABLE_CODE_ERROR`] (at most 65536 entries).
    pub fn build(inverse: &Inverse) -> Result<DirectTable, DisplayError> {
        let (f_lo, f_hi) = inverse.range();
        let at = |u: f64| f_lo + (f_hi - f_lo) * u.powi(4);
        let mut n = TABLE_ENTRIES;
        loop {
            let step = 1.0 / (n - 1) as f64;
            let codes: Vec<f64> = (0..n).map(|i| inverse.code(at(i as f64 * step))).collect();
            let mut err = 0.0f64;
            for (i, w) in codes.windows(2).enumerate() {
                for s in [0.25, 0.5, 0.75] {
                    let exact = inverse.code(at((i as f64 + s) * step));
                    err = err.max((w[0] + s * (w[1] - w[0]) - exact).abs());
                }
            }
            if err <= MAX_TABLE_CODE_ERROR {
                return Ok(DirectTable {
                    codes: codes.iter().map(|&c| c as f32).collect(),
                    max_code_error: err,
                });
            }
            if n >= 16 * TABLE_ENTRIES {
                return Err(DisplayError::Table {
                    got: err,
                    entries: n,
                    max_code_error: MAX_TABLE_CODE_ERROR,
                });
            }
            n *= 2;
        }
    }
}

/// The inverse calibration on the GPU.
struct Lut {
    buffer: wgpu::Buffer,
    entries: u32,
    code_lo: f32,
    code_hi: f32,
    f_lo: f32,
    f_hi: f32,
}

/// The frame being shown: the region's F_eff and where and how it is drawn.
struct Input {
    region_px: [u32; 2],
    buffer: wgpu::Buffer,
    origin_px: [u32; 2],
    /// 0 none, 1 ordered, 2 blue noise (`lut.wgsl`'s `dither_kind`).
    dither: u32,
}

/// One target's view of the inputs: its own parameters (the view scale differs between the
/// screen and a preview) and the bind group naming the current buffers.
pub(crate) struct Binding {
    params: wgpu::Buffer,
    group: wgpu::BindGroup,
    generation: u64,
}

/// The off-screen target: the screen's codes, two per `u32` (low half first), and the
/// buffer they are read back through.
struct Offscreen {
    screen_px: [u32; 2],
    /// A colour screen's target: one word per pixel, R | G << 10 | B << 20.
    colour: bool,
    codes: wgpu::Buffer,
    readback: wgpu::Buffer,
    words_per_row: u32,
    out_group: wgpu::BindGroup,
    binding: Option<Binding>,
}

pub struct Presenter {
    instance: wgpu::Instance,
    adapter: wgpu::Adapter,
    device: wgpu::Device,
    queue: wgpu::Queue,
    shader: wgpu::ShaderModule,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    /// Render pipelines by target format, dither kind and colour.
    pipelines: Vec<((wgpu::TextureFormat, u32, bool), wgpu::RenderPipeline)>,
    out_layout: wgpu::BindGroupLayout,
    compute_layout: wgpu::PipelineLayout,
    /// Off-screen compute pipelines by dither kind and colour.
    computes: Vec<((u32, bool), wgpu::ComputePipeline)>,
    bits: u32,
    lut: Option<Lut>,
    table_error: f64,
    input: Option<Input>,
    /// Bumped whenever the LUT or the input buffer is replaced (bindings then rebuild).
    generation: u64,
    offscreen: Option<Offscreen>,
    scratch: Vec<f32>,
    /// The blue-noise dither's thresholds.
    noise: wgpu::Buffer,
    /// A colour screen's parameters (`lut.wgsl`'s `colour`), and its camera's bands (0: a
    /// grey screen).
    colour: wgpu::Buffer,
    colour_bands: u32,
}

impl Presenter {
    /// A presenter on the default adapter (honours `WGPU_BACKEND`) for a `screen_bits` (8 or
    /// 10) screen, with no window.
    pub fn new_headless(screen_bits: u32) -> Result<Presenter, DisplayError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Presenter::with_instance(instance, screen_bits)
    }

    /// A presenter on `instance` (which, for windows, carries the display handle).
    pub fn with_instance(
        instance: wgpu::Instance,
        screen_bits: u32,
    ) -> Result<Presenter, DisplayError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..Default::default()
        }))
        .map_err(|e| DisplayError::NoAdapter(e.to_string()))?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("optistim presenter"),
            ..Default::default()
        }))
        .map_err(|e| DisplayError::Device(e.to_string()))?;
        let shader = device.create_shader_module(wgpu::include_wgsl!("lut.wgsl"));
        let visibility = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let storage = wgpu::BufferBindingType::Storage { read_only: true };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lut"),
            entries: &[
                buffer_entry(0, visibility, storage),
                buffer_entry(1, visibility, storage),
                buffer_entry(2, visibility, wgpu::BufferBindingType::Uniform),
                buffer_entry(3, visibility, storage),
                buffer_entry(4, visibility, storage),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lut"),
            bind_group_layouts: &[Some(&layout)],
            ..Default::default()
        });
        let out_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("screen codes"),
            entries: &[buffer_entry(
                0,
                wgpu::ShaderStages::COMPUTE,
                wgpu::BufferBindingType::Storage { read_only: false },
            )],
        });
        let compute_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lut (off-screen)"),
            bind_group_layouts: &[Some(&layout), Some(&out_layout)],
            ..Default::default()
        });
        let cells = crate::stimulator::dither::BLUE_NOISE_SIDE.pow(2) as f32;
        let thresholds: Vec<f32> = crate::stimulator::dither::blue_noise()
            .iter()
            .map(|&r| (r as f32 + 0.5) / cells)
            .collect();
        let noise = storage_buffer(&device, "blue noise", thresholds.len());
        queue.write_buffer(&noise, 0, bytemuck::cast_slice(&thresholds));
        let colour = storage_buffer(&device, "colour", 4);
        Ok(Presenter {
            colour,
            colour_bands: 0,
            noise,
            instance,
            out_layout,
            compute_layout,
            computes: Vec::new(),
            adapter,
            device,
            queue,
            shader,
            layout,
            pipeline_layout,
            pipelines: Vec::new(),
            bits: screen_bits,
            lut: None,
            table_error: 0.0,
            input: None,
            generation: 0,
            offscreen: None,
            scratch: Vec::new(),
        })
    }

    /// The adapter in words (name and backend), for logs and reports.
    pub fn adapter(&self) -> String {
        let info = self.adapter.get_info();
        format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
    }

    /// The direct table's interpolation error for the uploaded curve [codes].
    pub fn table_error(&self) -> f64 {
        self.table_error
    }

    /// Uploads the inverse calibration of a grey screen (again whenever the curve is
    /// replayed).
    pub fn set_inverse(&mut self, inverse: &Inverse) -> Result<(), DisplayError> {
        let table = DirectTable::build(inverse)?;
        self.set_tables(inverse, table.max_code_error, &table.codes);
        self.colour_bands = 0;
        Ok(())
    }

    /// Uploads what shows a stimulator's frames ([`Stimulator::drive`]): a grey screen's
    /// inverse or a colour screen's calibration.
    ///
    /// [`Stimulator::drive`]: crate::stimulator::Stimulator::drive
    pub fn set_drive(&mut self, drive: &Drive) -> Result<(), DisplayError> {
        match drive {
            Drive::Grey(inverse) => self.set_inverse(inverse),
            Drive::Colour {
                inverses,
                crosstalk,
                dither_shift,
            } => self.set_colour(inverses, crosstalk, *dither_shift),
        }
    }

    /// Uploads a colour screen's calibration: its primaries' inverses (R, G, B), the
    /// cross-talk with the camera's bands, and the dither shift
    /// ([`crate::stimulator::Stimulator::dither_shift`]). Frames then carry one F_eff plane
    /// per band.
    pub fn set_colour(
        &mut self,
        inverses: &[Inverse],
        crosstalk: &Crosstalk,
        dither_shift: u32,
    ) -> Result<(), DisplayError> {
        let bands = crosstalk.bands();
        let mut words = vec![0u32; 4 + 8 * PRIMARIES + PRIMARIES * bands];
        words[0] = bands as u32;
        words[1] = dither_shift;
        let mut codes = Vec::new();
        let mut worst = 0.0f64;
        for (c, inverse) in inverses.iter().enumerate().take(PRIMARIES) {
            let table = DirectTable::build(inverse)?;
            worst = worst.max(table.max_code_error);
            let (code_lo, code_hi) = inverse.codes();
            let (f_lo, f_hi) = inverse.range();
            let w = &mut words[4 + 8 * c..12 + 8 * c];
            w[0] = (code_lo as f32).to_bits();
            w[1] = (code_hi as f32).to_bits();
            w[2] = (f_lo as f32).to_bits();
            w[3] = (f_hi as f32).to_bits();
            w[4] = (1.0 / (f_hi as f32 - f_lo as f32)).to_bits();
            w[5] = codes.len() as u32;
            w[6] = table.codes.len() as u32;
            codes.extend_from_slice(&table.codes);
        }
        for c in 0..PRIMARIES {
            for b in 0..bands {
                words[4 + 8 * PRIMARIES + c * bands + b] = (crosstalk.p[c][b] as f32).to_bits();
            }
        }
        self.colour = storage_buffer(&self.device, "colour", words.len());
        self.queue
            .write_buffer(&self.colour, 0, bytemuck::cast_slice(&words));
        self.set_tables(&inverses[0], worst, &codes);
        self.colour_bands = bands as u32;
        Ok(())
    }

    /// Uploads direct tables (a grey screen's one; a colour screen's three, one after the
    /// other); `inverse` gives the grey pass its parameters.
    fn set_tables(&mut self, inverse: &Inverse, max_code_error: f64, codes: &[f32]) {
        let n = codes.len();
        let buffer = storage_buffer(&self.device, "inverse calibration", n);
        self.queue
            .write_buffer(&buffer, 0, bytemuck::cast_slice(codes));
        let (code_lo, code_hi) = inverse.codes();
        let (f_lo, f_hi) = inverse.range();
        self.lut = Some(Lut {
            buffer,
            entries: n as u32,
            code_lo: code_lo as f32,
            code_hi: code_hi as f32,
            f_lo: f_lo as f32,
            f_hi: f_hi as f32,
        });
        self.table_error = max_code_error;
        self.generation += 1;
    }

    /// Uploads one frame: `feff_region` is the screen region's F_eff (region size, row-major,
    /// after the collimator mapping and the transmittance; for a colour screen one such plane
    /// per camera band). Returns the time taken [ms].
    pub fn upload(
        &mut self,
        config: &StimulatorConfig,
        region_px: [usize; 2],
        feff_region: &[f64],
    ) -> Result<f64, DisplayError> {
        let t0 = Instant::now();
        let want = region_px[0] * region_px[1] * self.colour_bands.max(1) as usize;
        if feff_region.len() != want {
            return Err(DisplayError::RegionSize {
                got: feff_region.len(),
                want,
            });
        }
        let region = [region_px[0] as u32, region_px[1] as u32];
        if self
            .input
            .as_ref()
            .is_none_or(|i| i.region_px != region || i.buffer.size() != 4 * want.max(1) as u64)
        {
            let buffer = storage_buffer(&self.device, "feff", want);
            self.input = Some(Input {
                region_px: region,
                buffer,
                origin_px: [0, 0],
                dither: 0,
            });
            self.generation += 1;
        }
        let mut scratch = std::mem::take(&mut self.scratch);
        {
            use rayon::prelude::*;
            feff_region
                .par_iter()
                .map(|&x| x as f32)
                .collect_into_vec(&mut scratch);
        }
        let input = self.input.as_mut().expect("made above");
        input.origin_px = [config.origin_px[0] as u32, config.origin_px[1] as u32];
        input.dither = match config.dither {
            Dither::None => 0,
            Dither::Ordered => 1,
            Dither::BlueNoise => 2,
        };
        self.queue
            .write_buffer(&input.buffer, 0, bytemuck::cast_slice(&scratch));
        self.scratch = scratch;
        Ok(ms(t0))
    }

    /// Computes the uploaded frame's codes for a whole `screen_px` screen off-screen and
    /// reads them back, one `u16` per screen pixel (a colour screen's three planes, R, G, B,
    /// one after the other). The same `screen_code` as the windows'
    /// pass, run as a compute pass into a buffer (on a software rasteriser, rasterising the
    /// screen costs more than the LUT itself).
    pub fn render_offscreen(
        &mut self,
        screen_px: [usize; 2],
        out: &mut Vec<u16>,
    ) -> Result<PresentTimings, DisplayError> {
        let mut t = PresentTimings::default();
        let t0 = Instant::now();
        let screen = [screen_px[0] as u32, screen_px[1] as u32];
        let colour = self.colour_bands > 0;
        if self
            .offscreen
            .as_ref()
            .is_none_or(|o| o.screen_px != screen || o.colour != colour)
        {
            let words_per_row = if colour {
                screen[0]
            } else {
                screen[0].div_ceil(2)
            };
            let size = (4 * words_per_row * screen[1]) as u64;
            let buffer = |label, usage| buffer(&self.device, label, size, usage);
            let codes = buffer(
                "screen codes",
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            );
            let readback = buffer(
                "screen read-back",
                wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            );
            let out_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("screen codes"),
                layout: &self.out_layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: codes.as_entire_binding(),
                }],
            });
            self.offscreen = Some(Offscreen {
                screen_px: screen,
                colour,
                codes,
                readback,
                words_per_row,
                out_group,
                binding: None,
            });
        }
        let mut off = self.offscreen.take().expect("made above");
        let compute = self.compute_pipeline();
        let encoded = self.bind(&mut off.binding, screen, [1.0; 2]).map(|b| {
            let mut encoder = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lut") });
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                pass.set_pipeline(&compute);
                pass.set_bind_group(0, &b.group, &[]);
                pass.set_bind_group(1, &off.out_group, &[]);
                // Two words per invocation for a grey screen, four for a colour one.
                let per_group = if colour { 256 } else { 128 };
                pass.dispatch_workgroups(off.words_per_row.div_ceil(per_group), screen[1], 1);
            }
            encoder.copy_buffer_to_buffer(&off.codes, 0, &off.readback, 0, off.codes.size());
            self.queue.submit([encoder.finish()]);
        });
        t.lut_pass = ms(t0);
        let result = encoded.and_then(|()| {
            let t0 = Instant::now();
            self.read_codes(&off, out)?;
            t.readback = ms(t0);
            Ok(t)
        });
        self.offscreen = Some(off);
        result
    }

    /// Upload, LUT pass and read-back of one frame off-screen: the screen's codes, one `u16`
    /// per screen pixel.
    pub fn draw_offscreen(
        &mut self,
        config: &StimulatorConfig,
        region_px: [usize; 2],
        feff_region: &[f64],
        out: &mut Vec<u16>,
    ) -> Result<PresentTimings, DisplayError> {
        let upload = self.upload(config, region_px, feff_region)?;
        let mut t = self.render_offscreen(config.screen_px, out)?;
        t.upload = upload;
        Ok(t)
    }

    /// Maps the read-back buffer and copies out one code per pixel.
    fn read_codes(&self, off: &Offscreen, out: &mut Vec<u16>) -> Result<(), DisplayError> {
        let [w, h] = off.screen_px.map(|x| x as usize);
        let slice = off.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| DisplayError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| DisplayError::Readback(e.to_string()))?
            .map_err(|e| DisplayError::Readback(e.to_string()))?;
        {
            let mapped = slice
                .get_mapped_range()
                .map_err(|e| DisplayError::Readback(e.to_string()))?;
            out.clear();
            if off.colour {
                out.resize(PRIMARIES * w * h, 0);
                let words: &[u32] = bytemuck::cast_slice(&mapped[..4 * w * h]);
                let (r, rest) = out.split_at_mut(w * h);
                let (g, b) = rest.split_at_mut(w * h);
                for (i, &x) in words.iter().enumerate() {
                    r[i] = (x & 0x3ff) as u16;
                    g[i] = (x >> 10 & 0x3ff) as u16;
                    b[i] = (x >> 20 & 0x3ff) as u16;
                }
            } else {
                out.resize(w * h, 0);
                let row_bytes = 4 * off.words_per_row as usize;
                for (dst, row) in out.chunks_exact_mut(w).zip(mapped.chunks(row_bytes)) {
                    dst.copy_from_slice(bytemuck::cast_slice(&row[..2 * w]));
                }
            }
        }
        off.readback.unmap();
        Ok(())
    }

    /// Makes `binding` current (rebuilt when the LUT or the input texture changed) and writes
    /// its parameters for a `target_px` target showing `view_scale` screen pixels per target
    /// pixel.
    fn bind<'b>(
        &self,
        binding: &'b mut Option<Binding>,
        target_px: [u32; 2],
        view_scale: [f32; 2],
    ) -> Result<&'b Binding, DisplayError> {
        let lut = self.lut.as_ref().ok_or(DisplayError::NoCalibration)?;
        let input = self.input.as_ref().ok_or(DisplayError::NoFrame)?;
        if binding
            .as_ref()
            .is_none_or(|b| b.generation != self.generation)
        {
            let params = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("lut params"),
                size: 64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("lut"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: input.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: lut.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.noise.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: self.colour.as_entire_binding(),
                    },
                ],
            });
            *binding = Some(Binding {
                params,
                group,
                generation: self.generation,
            });
        }
        let b = binding.as_ref().expect("made above");
        let top = ((1u32 << self.bits) - 1) as f32;
        let params: [u32; 16] = [
            input.origin_px[0],
            input.origin_px[1],
            input.region_px[0],
            input.region_px[1],
            view_scale[0].to_bits(),
            view_scale[1].to_bits(),
            lut.code_lo.to_bits(),
            lut.code_hi.to_bits(),
            top.to_bits(),
            lut.f_lo.to_bits(),
            lut.f_hi.to_bits(),
            lut.entries,
            (1.0 / (lut.f_hi - lut.f_lo)).to_bits(),
            0,
            target_px[0],
            target_px[1],
        ];
        self.queue
            .write_buffer(&b.params, 0, bytemuck::cast_slice(&params));
        Ok(b)
    }

    /// The LUT pass into `view` (a `target_px` texture of `format`, a window's), with
    /// `view_scale` screen pixels per target pixel; `binding` is the target's own.
    pub(crate) fn encode_pass(
        &mut self,
        binding: &mut Option<Binding>,
        view: &wgpu::TextureView,
        format: wgpu::TextureFormat,
        target_px: [u32; 2],
        view_scale: [f32; 2],
    ) -> Result<wgpu::CommandEncoder, DisplayError> {
        let pipeline = self.pipeline(format).clone();
        let b = self.bind(binding, target_px, view_scale)?;
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lut") });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("lut"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    resolve_target: None,
                    depth_slice: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                ..Default::default()
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &b.group, &[]);
            pass.draw(0..3, 0..1);
        }
        Ok(encoder)
    }

    /// The dither kind of the uploaded frame (`lut.wgsl`'s `dither_kind`).
    fn dither_kind(&self) -> u32 {
        self.input.as_ref().map_or(0, |i| i.dither)
    }

    /// The off-screen compute pipeline for the uploaded frame's dither and the screen's
    /// colour (made once per pair).
    fn compute_pipeline(&mut self) -> wgpu::ComputePipeline {
        let kind = self.dither_kind();
        let colour = self.colour_bands > 0;
        if let Some((_, p)) = self.computes.iter().find(|(k, _)| *k == (kind, colour)) {
            return p.clone();
        }
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("lut (off-screen)"),
                layout: Some(&self.compute_layout),
                module: &self.shader,
                entry_point: Some(if colour { "cs_rgb" } else { "cs_codes" }),
                compilation_options: dither_constant(kind),
                cache: None,
            });
        self.computes.push(((kind, colour), pipeline.clone()));
        pipeline
    }

    /// The LUT pipeline for a target format and the uploaded frame's dither (made once per
    /// pair).
    fn pipeline(&mut self, format: wgpu::TextureFormat) -> &wgpu::RenderPipeline {
        let key = (format, self.dither_kind(), self.colour_bands > 0);
        if let Some(i) = self.pipelines.iter().position(|(k, _)| *k == key) {
            return &self.pipelines[i].1;
        }
        let pipeline = self
            .device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("lut"),
                layout: Some(&self.pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &self.shader,
                    entry_point: Some("vs_main"),
                    buffers: &[],
                    compilation_options: Default::default(),
                },
                fragment: Some(wgpu::FragmentState {
                    module: &self.shader,
                    entry_point: Some(if key.2 { "fs_rgb" } else { "fs_main" }),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                    compilation_options: dither_constant(key.1),
                }),
                primitive: Default::default(),
                depth_stencil: None,
                multisample: Default::default(),
                multiview_mask: None,
                cache: None,
            });
        self.pipelines.push((key, pipeline));
        &self.pipelines.last().expect("pushed").1
    }
}

/// A storage buffer of `n` f32 values, written by the queue.
fn storage_buffer(device: &wgpu::Device, label: &str, n: usize) -> wgpu::Buffer {
    buffer(
        device,
        label,
        (4 * n.max(1)) as u64,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    )
}

fn buffer(
    device: &wgpu::Device,
    label: &str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage,
        mapped_at_creation: false,
    })
}

/// The shader's `dither_kind` pipeline constant.
fn dither_constant(kind: u32) -> wgpu::PipelineCompilationOptions<'static> {
    const KINDS: [[(&str, f64); 1]; 3] = [
        [("dither_kind", 0.0)],
        [("dither_kind", 1.0)],
        [("dither_kind", 2.0)],
    ];
    wgpu::PipelineCompilationOptions {
        constants: &KINDS[kind.min(2) as usize],
        ..Default::default()
    }
}

/// A bind-group-layout entry for a buffer.
fn buffer_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
    ty: wgpu::BufferBindingType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stimulator::calibration::{Curve, Interp};

    /// The example curve tabulates well inside the error bound at 10 bit and at 8 bit.
    #[test]
    fn direct_table_of_the_example_curve_is_accurate() {
        let example = crate::stimulator::calibration::tests::EXAMPLE;
        let curve = Curve::parse(example.as_bytes(), "example", "example", Interp::Pchip).unwrap();
        for levels in [256, 1024] {
            let t = DirectTable::build(&curve.inverse(0, levels)).unwrap();
            assert!(
                t.max_code_error <= MAX_TABLE_CODE_ERROR,
                "{}",
                t.max_code_error
            );
            assert!(t.codes.windows(2).all(|w| w[1] >= w[0]));
        }
    }
}
