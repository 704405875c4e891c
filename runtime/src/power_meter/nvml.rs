//! NVIDIA GPUs through NVML, loaded at run time from the driver's `libnvidia-ml.so.1`: nothing
//! NVIDIA is needed to build qosrt, and a machine without the driver simply has no NVML meter.
//! The reading is the sum of every GPU's `nvmlDeviceGetPowerUsage` (mW): the GPUs' power only,
//! not the board's.

use super::{MeterError, PowerMeter, PowerReading};
use libloading::Library;
use std::ffi::{c_char, c_uint, c_void, CStr};
use std::path::{Path, PathBuf};

pub const NAME: &str = "nvml";
/// The library as the NVIDIA driver installs it; found through the dynamic linker's path.
pub const DEFAULT_LIBRARY: &str = "libnvidia-ml.so.1";

type NvmlReturn = c_uint;
type Device = *mut c_void;
const NVML_SUCCESS: NvmlReturn = 0;
const NAME_BUFFER: usize = 96;

type InitFn = unsafe extern "C" fn() -> NvmlReturn;
type CountFn = unsafe extern "C" fn(*mut c_uint) -> NvmlReturn;
type HandleFn = unsafe extern "C" fn(c_uint, *mut Device) -> NvmlReturn;
type PowerFn = unsafe extern "C" fn(Device, *mut c_uint) -> NvmlReturn;
type NameFn = unsafe extern "C" fn(Device, *mut c_char, c_uint) -> NvmlReturn;
type ErrorStringFn = unsafe extern "C" fn(NvmlReturn) -> *const c_char;

/// The NVML functions used, resolved once. They stay valid while `_library` is loaded, and
/// [`NvmlMeter`] keeps both together.
struct Api {
    shutdown: InitFn,
    power_usage: PowerFn,
    error_string: Option<ErrorStringFn>,
}

/// Every GPU NVML sees.
pub struct NvmlMeter {
    api: Api,
    devices: Vec<(String, Device)>,
    library_path: PathBuf,
    // Dropped last (fields drop in order), after `Drop` has called nvmlShutdown.
    _library: Library,
}

impl NvmlMeter {
    /// Loads the library, initialises NVML and finds the GPUs; the error says why not.
    pub fn open(library_path: &Path) -> Result<NvmlMeter, MeterError> {
        // SAFETY: loading the NVIDIA driver's NVML library runs its initialisers, which have no
        // preconditions on our side.
        let library = unsafe { Library::new(library_path) }
            .map_err(|source| MeterError::NvmlLoad { source })?;
        // SAFETY: the symbols are looked up by the names and C signatures of NVML's public
        // header (nvml.h); the function pointers are used only while `library` is loaded.
        let (init, count, handle, name, api) = unsafe {
            let symbol =
                |symbol: &'static str| move |source| MeterError::NvmlSymbol { symbol, source };
            let init: InitFn = *library
                .get::<InitFn>("nvmlInit_v2")
                .map_err(symbol("nvmlInit_v2"))?;
            let shutdown: InitFn = *library
                .get::<InitFn>("nvmlShutdown")
                .map_err(symbol("nvmlShutdown"))?;
            let count: CountFn = *library
                .get::<CountFn>("nvmlDeviceGetCount_v2")
                .map_err(symbol("nvmlDeviceGetCount_v2"))?;
            let handle: HandleFn = *library
                .get::<HandleFn>("nvmlDeviceGetHandleByIndex_v2")
                .map_err(symbol("nvmlDeviceGetHandleByIndex_v2"))?;
            let power_usage: PowerFn = *library
                .get::<PowerFn>("nvmlDeviceGetPowerUsage")
                .map_err(symbol("nvmlDeviceGetPowerUsage"))?;
            let name: Option<NameFn> = library.get::<NameFn>("nvmlDeviceGetName").ok().map(|s| *s);
            let error_string: Option<ErrorStringFn> = library
                .get::<ErrorStringFn>("nvmlErrorString")
                .ok()
                .map(|s| *s);
            (
                init,
                count,
                handle,
                name,
                Api {
                    shutdown,
                    power_usage,
                    error_string,
                },
            )
        };
        // SAFETY: nvmlInit_v2 takes no arguments.
        let code = unsafe { init() };
        if code != NVML_SUCCESS {
            return Err(api.error("nvmlInit_v2", code));
        }
        let mut meter = NvmlMeter {
            api,
            devices: Vec::new(),
            library_path: library_path.to_path_buf(),
            _library: library,
        };
        // From here on `meter`'s Drop shuts NVML down on every early return.
        let mut n: c_uint = 0;
        // SAFETY: NVML is initialised; `n` is a valid out-pointer.
        let code = unsafe { count(&mut n) };
        if code != NVML_SUCCESS {
            return Err(meter.api.error("nvmlDeviceGetCount_v2", code));
        }
        for index in 0..n {
            let mut device: Device = std::ptr::null_mut();
            // SAFETY: `index` < the count NVML gave; `device` is a valid out-pointer.
            let code = unsafe { handle(index, &mut device) };
            if code != NVML_SUCCESS {
                return Err(meter.api.error("nvmlDeviceGetHandleByIndex_v2", code));
            }
            let mut label = format!("GPU {index}");
            if let Some(name) = name {
                let mut buffer = [0 as c_char; NAME_BUFFER];
                // SAFETY: the buffer holds NAME_BUFFER bytes, which NVML is told; on success
                // it writes a NUL-terminated string into it.
                if unsafe { name(device, buffer.as_mut_ptr(), NAME_BUFFER as c_uint) }
                    == NVML_SUCCESS
                {
                    // SAFETY: NUL-terminated by NVML, within the buffer.
                    let text = unsafe { CStr::from_ptr(buffer.as_ptr()) };
                    label = format!("GPU {index} ({})", text.to_string_lossy());
                }
            }
            meter.devices.push((label, device));
        }
        if meter.devices.is_empty() {
            return Err(MeterError::NvmlNoGpu);
        }
        // A GPU without power readings (some consumer boards) cannot be used.
        meter.read()?;
        Ok(meter)
    }
}

impl Api {
    fn error(&self, call: &'static str, code: NvmlReturn) -> MeterError {
        let message = match self.error_string {
            // SAFETY: nvmlErrorString returns a static NUL-terminated string for any code.
            Some(f) => unsafe {
                let text = f(code);
                if text.is_null() {
                    "unknown error".to_string()
                } else {
                    CStr::from_ptr(text).to_string_lossy().into_owned()
                }
            },
            None => "unknown error".to_string(),
        };
        MeterError::Nvml {
            call,
            code,
            message,
        }
    }
}

impl PowerMeter for NvmlMeter {
    fn name(&self) -> &str {
        NAME
    }

    fn describe(&self) -> String {
        format!(
            "NVML ({}): total = sum of {} (GPU power only, not the board's)",
            self.library_path.display(),
            self.rails().join(" + ")
        )
    }

    fn rails(&self) -> Vec<String> {
        self.devices
            .iter()
            .map(|(label, _)| label.clone())
            .collect()
    }

    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let mut rails_w = Vec::with_capacity(self.devices.len());
        for (_, device) in &self.devices {
            let mut mw: c_uint = 0;
            // SAFETY: `device` is a handle NVML gave and NVML is initialised until Drop.
            let code = unsafe { (self.api.power_usage)(*device, &mut mw) };
            if code != NVML_SUCCESS {
                return Err(self.api.error("nvmlDeviceGetPowerUsage", code));
            }
            rails_w.push(mw as f64 * 1e-3);
        }
        let total_w: f64 = rails_w.iter().sum();
        Ok(PowerReading {
            total_w,
            cpu_w: None,
            gpu_w: Some(total_w),
            rails_w,
        })
    }
}

impl Drop for NvmlMeter {
    fn drop(&mut self) {
        // SAFETY: NVML was initialised in `open` (a meter exists only then); the library is
        // still loaded (it is dropped after this).
        unsafe {
            (self.api.shutdown)();
        }
    }
}
