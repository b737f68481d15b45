//! One wgpu device per process.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use super::GpuError;

/// An open GPU: adapter, device and queue, and what the adapter offers.
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    f64: bool,
    /// Largest storage-buffer binding, bytes.
    pub(crate) max_binding: u64,
    /// Largest buffer, bytes.
    pub(crate) max_buffer: u64,
    /// Largest workgroup count per dispatch dimension.
    pub(crate) max_groups: u32,
    /// Largest workgroup: invocations, and bytes of workgroup memory.
    pub(crate) max_invocations: u32,
    pub(crate) max_workgroup_bytes: u32,
    /// Compiled pipelines by shader source: a cell run builds an FMM (and a pair sum) every
    /// step, and compiling WGSL each time costs more than the sums.
    pipelines: Mutex<HashMap<String, wgpu::ComputePipeline>>,
}

static SHARED: OnceLock<Result<Arc<Gpu>, GpuError>> = OnceLock::new();

impl Gpu {
    /// The process's GPU, opened on first use (the adapter wgpu prefers for high performance;
    /// `WGPU_BACKEND` and `WGPU_ADAPTER_NAME` narrow the choice).
    pub fn shared() -> Result<Arc<Gpu>, GpuError> {
        SHARED.get_or_init(|| Gpu::open().map(Arc::new)).clone()
    }

    fn open() -> Result<Gpu, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        };
        let adapter = pollster::block_on(instance.request_adapter(&options))
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        let limits = adapter.limits();
        let desc = wgpu::DeviceDescriptor {
            label: Some("mobo"),
            required_features: if f64 {
                wgpu::Features::SHADER_F64
            } else {
                wgpu::Features::empty()
            },
            required_limits: limits.clone(),
            ..Default::default()
        };
        let (device, queue) =
            pollster::block_on(adapter.request_device(&desc)).map_err(|e| GpuError::Device {
                adapter: info.name.clone(),
                reason: e.to_string(),
            })?;
        Ok(Gpu {
            device,
            queue,
            f64,
            max_binding: (limits.max_storage_buffer_binding_size as u64)
                .min(limits.max_buffer_size),
            max_buffer: limits.max_buffer_size,
            max_groups: limits.max_compute_workgroups_per_dimension,
            max_invocations: limits
                .max_compute_invocations_per_workgroup
                .min(limits.max_compute_workgroup_size_x),
            max_workgroup_bytes: limits.max_compute_workgroup_storage_size,
            pipelines: Mutex::new(HashMap::new()),
            info,
        })
    }

    /// The compute pipeline of WGSL `source` (entry point `main`, layout from the shader),
    /// compiled once per process without runtime bounds checks.
    ///
    /// # Safety
    /// Every index `source` forms must be in bounds for the buffers bound to it.
    pub(crate) unsafe fn trusted_pipeline(
        &self,
        label: &str,
        source: &str,
    ) -> wgpu::ComputePipeline {
        let mut cache = self.pipelines.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(p) = cache.get(source) {
            return p.clone();
        }
        let desc = wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        };
        // SAFETY: the caller's promise (indices in bounds).
        let module = unsafe {
            self.device
                .create_shader_module_trusted(desc, wgpu::ShaderRuntimeChecks::unchecked())
        };
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
        cache.insert(source.to_string(), pipeline.clone());
        pipeline
    }

    /// An uninitialised (zeroed) buffer of `size` bytes, at least 16 (a binding may not be
    /// empty).
    pub(crate) fn buffer(
        &self,
        label: &str,
        size: usize,
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16) as u64,
            usage,
            mapped_at_creation: false,
        })
    }

    /// The bind group of `pipeline`'s group 0 from `(binding, buffer)` pairs (the layout is
    /// derived from the shader, so the pairs must name exactly the bindings it declares).
    pub(crate) fn bind_group(
        &self,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .map(|&(binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Wait until the device has finished everything submitted.
    pub(crate) fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Execution(e.to_string()))
    }

    /// Map `slice` of a read-back buffer (filled by a submitted copy) and wait until it is
    /// readable.
    pub(crate) fn map_read(&self, slice: &wgpu::BufferSlice) -> Result<(), GpuError> {
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Execution(e.to_string()))?
            .map_err(|e| GpuError::Execution(e.to_string()))
    }

    /// Whether `f64` shaders are available.
    pub fn has_f64(&self) -> bool {
        self.f64
    }

    /// Whether the adapter is a hardware GPU (not a CPU rasteriser such as lavapipe).
    pub fn is_hardware(&self) -> bool {
        matches!(
            self.info.device_type,
            wgpu::DeviceType::DiscreteGpu | wgpu::DeviceType::IntegratedGpu
        )
    }

    /// `"NVIDIA H100 … (Vulkan)"`.
    pub fn describe(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }
}
