//! The presenter: one wgpu device and queue, and the LUT pass that turns the screen region's
//! F_eff into screen DN codes on the GPU (`lut.wgsl`: the same bisection, interpolation and
//! dithering as [`crate::stimulator::calibration::Inverse::apply`], in f32).
//!
//! Targets: an off-screen texture read back to memory (here; tests and headless runs). The
//! borderless fullscreen window and the operator's preview window are still to come (issue 4).
//! The presenter never runs on the async runtime; `pollster` blocks on wgpu's futures.

use crate::stimulator::StimulatorConfig;
use crate::stimulator::calibration::{INVERSE_SUBSTEPS, Inverse};
use crate::stimulator::dither::Dither;
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
}

/// Time per presenter stage [ms].
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PresentTimings {
    pub upload: f64,
    pub lut_pass: f64,
    pub readback: f64,
}

/// Per-screen GPU resources.
struct Target {
    screen_px: [u32; 2],
    region_px: [u32; 2],
    feff: wgpu::Texture,
    out: wgpu::Texture,
    readback: wgpu::Buffer,
    padded_row: u32,
    bind_group: wgpu::BindGroup,
}

/// The inverse calibration on the GPU: F_eff at every quarter code, and its scalars.
struct Lut {
    texture: wgpu::Texture,
    entries: u32,
    code_lo: f32,
    code_hi: f32,
    f_lo: f32,
    f_hi: f32,
}

pub struct Presenter {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: wgpu::AdapterInfo,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
    params: wgpu::Buffer,
    lut: Option<Lut>,
    target: Option<Target>,
    top: f32,
}

impl Presenter {
    /// A presenter on the default adapter (honours `WGPU_BACKEND`) for `screen_bits` (8: rgba8,
    /// 10: rgb10a2) output.
    pub fn new_headless(screen_bits: u32) -> Result<Presenter, DisplayError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
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
        let format = if screen_bits > 8 {
            wgpu::TextureFormat::Rgb10a2Unorm
        } else {
            wgpu::TextureFormat::Rgba8Unorm
        };
        let shader = device.create_shader_module(wgpu::include_wgsl!("lut.wgsl"));
        let texture_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lut"),
            entries: &[
                texture_entry(0),
                texture_entry(1),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lut"),
            bind_group_layouts: &[Some(&layout)],
            ..Default::default()
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("lut"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                buffers: &[],
                compilation_options: Default::default(),
            },
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_main"),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
                compilation_options: Default::default(),
            }),
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            multiview_mask: None,
            cache: None,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lut params"),
            size: 48,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Presenter {
            device,
            queue,
            adapter: adapter.get_info(),
            pipeline,
            layout,
            format,
            params,
            lut: None,
            target: None,
            top: ((1u32 << screen_bits) - 1) as f32,
        })
    }

    /// The adapter in words (name and backend), for logs and reports.
    pub fn adapter(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.adapter.name, self.adapter.backend, self.adapter.device_type
        )
    }

    /// Uploads the inverse calibration table (again whenever the curve is replayed).
    pub fn set_inverse(&mut self, inverse: &Inverse) {
        let table: Vec<f32> = inverse.table().iter().map(|&x| x as f32).collect();
        let n = table.len() as u32;
        let tex = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("inverse calibration"),
            size: wgpu::Extent3d {
                width: n,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        write_r32(&self.queue, &tex, &table, [n, 1]);
        let (code_lo, code_hi) = inverse.codes();
        let (f_lo, f_hi) = inverse.range();
        self.lut = Some(Lut {
            texture: tex,
            entries: n,
            code_lo: code_lo as f32,
            code_hi: code_hi as f32,
            f_lo: f_lo as f32,
            f_hi: f_hi as f32,
        });
        self.target = None; // its bind group names the old table
    }

    /// (Re)creates the per-screen resources when the screen or region size changes.
    fn ensure_target(&mut self, screen_px: [u32; 2], region_px: [u32; 2]) {
        let fits = self
            .target
            .as_ref()
            .is_some_and(|t| t.screen_px == screen_px && t.region_px == region_px);
        if !fits {
            let texture = |label, [w, h]: [u32; 2], format, usage| {
                self.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: w,
                        height: h,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
            };
            let feff = texture(
                "feff",
                region_px,
                wgpu::TextureFormat::R32Float,
                wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            );
            let out = texture(
                "screen",
                screen_px,
                self.format,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            );
            let padded_row = (4 * screen_px[0]).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
                * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
            let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("screen read-back"),
                size: (padded_row * screen_px[1]) as u64,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            let table = &self
                .lut
                .as_ref()
                .expect("checked by draw_offscreen")
                .texture;
            let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("lut"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(
                            &feff.create_view(&Default::default()),
                        ),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(
                            &table.create_view(&Default::default()),
                        ),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.params.as_entire_binding(),
                    },
                ],
            });
            self.target = Some(Target {
                screen_px,
                region_px,
                feff,
                out,
                readback,
                padded_row,
                bind_group,
            });
        }
    }

    /// Draws one frame off-screen: `feff_region` is the screen region's F_eff (region size,
    /// row-major, after the collimator mapping and the transmittance), the LUT pass writes the
    /// whole screen, and the codes come back as one `u16` per screen pixel.
    pub fn draw_offscreen(
        &mut self,
        config: &StimulatorConfig,
        region_px: [usize; 2],
        feff_region: &[f64],
        out: &mut Vec<u16>,
    ) -> Result<PresentTimings, DisplayError> {
        let want = region_px[0] * region_px[1];
        if feff_region.len() != want {
            return Err(DisplayError::RegionSize {
                got: feff_region.len(),
                want,
            });
        }
        let mut t = PresentTimings::default();
        let t0 = Instant::now();
        let lut = self
            .lut
            .as_ref()
            .ok_or_else(|| DisplayError::Device("no calibration uploaded (set_inverse)".into()))?;
        let screen = [config.screen_px[0] as u32, config.screen_px[1] as u32];
        let region = [region_px[0] as u32, region_px[1] as u32];
        let params: [u32; 12] = [
            config.origin_px[0] as u32,
            config.origin_px[1] as u32,
            region[0],
            region[1],
            lut.code_lo.to_bits(),
            self.top.to_bits(),
            lut.f_lo.to_bits(),
            lut.f_hi.to_bits(),
            lut.entries,
            (INVERSE_SUBSTEPS as f32).to_bits(),
            u32::from(config.dither == Dither::Ordered),
            lut.code_hi.to_bits(),
        ];
        let bytes: Vec<u8> = params.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.queue.write_buffer(&self.params, 0, &bytes);
        let data: Vec<f32> = feff_region.iter().map(|&x| x as f32).collect();
        self.ensure_target(screen, region);
        let target = self.target.as_ref().expect("made above");
        write_r32(&self.queue, &target.feff, &data, region);
        t.upload = ms(t0);

        let t0 = Instant::now();
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lut") });
        {
            let view = target.out.create_view(&Default::default());
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("lut"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    resolve_target: None,
                    depth_slice: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                ..Default::default()
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &target.bind_group, &[]);
            pass.draw(0..3, 0..1);
        }
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &target.out,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &target.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(target.padded_row),
                    rows_per_image: Some(screen[1]),
                },
            },
            wgpu::Extent3d {
                width: screen[0],
                height: screen[1],
                depth_or_array_layers: 1,
            },
        );
        self.queue.submit([encoder.finish()]);
        t.lut_pass = ms(t0);

        let t0 = Instant::now();
        let slice = target.readback.slice(..);
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
            out.reserve((screen[0] * screen[1]) as usize);
            let ten_bit = self.format == wgpu::TextureFormat::Rgb10a2Unorm;
            for row in mapped.chunks(target.padded_row as usize) {
                for px in row[..4 * screen[0] as usize].chunks_exact(4) {
                    let word = u32::from_le_bytes([px[0], px[1], px[2], px[3]]);
                    out.push(if ten_bit {
                        (word & 0x3ff) as u16
                    } else {
                        px[0] as u16
                    });
                }
            }
        }
        target.readback.unmap();
        t.readback = ms(t0);
        Ok(t)
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn write_r32(queue: &wgpu::Queue, tex: &wgpu::Texture, data: &[f32], [w, h]: [u32; 2]) {
    let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: tex,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(4 * w),
            rows_per_image: Some(h),
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
}
