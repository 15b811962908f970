//! [`forward_device_context!`](crate::forward_device_context): a
//! simulation that owns its drive (and commits a frame's outbox at once)
//! is a [`DeviceContext`](crate::DeviceContext) by handing every call to
//! the service's [`Link`](crate::Link).
//!
//! The type provides two inherent methods:
//! - `fn view_parts(&self) -> (Snapshot, &Service)`: the drive now and its
//!   service (the read-only calls);
//! - `fn with_link<R>(&mut self, f: impl FnOnce(&mut Link<'_, S>) -> R) -> R`:
//!   a link on the drive now, `f` run on it, its outbox committed (the
//!   calls that change something).
//!
//! The scope does not go through the link: name the type's field that
//! holds one (`forward_device_context!(T, scope: field)`), or the drive
//! has none (the trait's default).

/// Implement [`DeviceContext`](crate::DeviceContext) for `$t` through its
/// `view_parts` and `with_link` (see the [module docs](crate::forward)).
#[macro_export]
macro_rules! forward_device_context {
    ($t:ty) => {
        $crate::forward_device_context!(@impl $t, {});
    };
    ($t:ty, scope: $field:ident) => {
        $crate::forward_device_context!(@impl $t, {
            fn scope(
                &mut self,
            ) -> ::core::option::Option<&mut dyn $crate::__deps::foc_protocol::scope::ScopePort> {
                ::core::option::Option::Some(&mut self.$field)
            }
        });
    };
    (@impl $t:ty, { $($extra:tt)* }) => {
        impl $crate::DeviceContext for $t {
            $($extra)*
            fn post(
                &mut self,
                cmd: $crate::__deps::foc_core::control::Command,
            ) -> ::core::result::Result<(), $crate::__deps::foc_core::control::CommandError> {
                self.with_link(|l| $crate::DeviceContext::post(l, cmd))
            }
            fn keep_alive(&mut self) {
                self.with_link(|l| $crate::DeviceContext::keep_alive(l))
            }
            fn mode(&self) -> $crate::__deps::foc_core::control::Mode {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .mode()
            }
            fn faults(
                &self,
            ) -> (
                $crate::__deps::foc_core::control::FaultSet,
                ::core::option::Option<$crate::__deps::foc_core::control::Fault>,
            ) {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .faults()
            }
            fn clear_faults(&mut self) {
                self.with_link(|l| $crate::DeviceContext::clear_faults(l))
            }
            fn report_fault(&mut self, fault: $crate::__deps::foc_core::control::Fault) {
                self.with_link(|l| $crate::DeviceContext::report_fault(l, fault))
            }
            fn limits(&self) -> $crate::__deps::foc_core::control::Limits {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .limits()
            }
            fn set_limits(
                &mut self,
                limits: $crate::__deps::foc_core::control::Limits,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_limits(l, limits))
            }
            fn joint(&self) -> $crate::__deps::foc_core::control::joint::JointSetup {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .joint()
            }
            fn set_joint(
                &mut self,
                setup: $crate::__deps::foc_core::control::joint::JointSetup,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_joint(l, setup))
            }
            fn torque_constant_nm_per_a(&self) -> f32 {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .torque_constant_nm_per_a()
            }
            fn feedback(&self) -> $crate::__deps::foc_core::control::Feedback {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .feedback()
            }
            fn set_current_gains(
                &mut self,
                gains: $crate::__deps::foc_protocol::message::CurrentGains,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_current_gains(l, gains))
            }
            fn set_speed_gains(
                &mut self,
                gains: $crate::__deps::foc_protocol::message::SpeedGains,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_speed_gains(l, gains))
            }
            fn set_position_gains(
                &mut self,
                gains: $crate::__deps::foc_protocol::message::PositionGains,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_position_gains(l, gains))
            }
            fn set_dividers(
                &mut self,
                speed: u16,
                position: u16,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_dividers(l, speed, position))
            }
            fn set_param(
                &mut self,
                id: $crate::__deps::foc_protocol::message::ParamId,
                value: f32,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::set_param(l, id, value))
            }
            fn start_calibration(
                &mut self,
                routine: $crate::__deps::foc_protocol::message::Calibration,
            ) -> ::core::result::Result<(), $crate::__deps::foc_protocol::Refusal> {
                self.with_link(|l| $crate::DeviceContext::start_calibration(l, routine))
            }
            fn is_calibrated(&self) -> bool {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .is_calibrated()
            }
            fn status(&self) -> $crate::__deps::foc_core::drive::Status {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .status()
            }
            fn param(
                &self,
                id: $crate::__deps::foc_protocol::message::ParamId,
            ) -> ::core::option::Option<f32> {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .param(id)
            }
            fn telemetry(&self) -> $crate::__deps::foc_protocol::message::Telemetry {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .telemetry()
            }
            fn firmware_version(&self) -> [u8; 3] {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .firmware_version()
            }
            fn max_stream_hz(&self) -> ::core::option::Option<f32> {
                let (snap, service) = self.view_parts();
                $crate::View {
                    snap: &snap,
                    service,
                }
                .max_stream_hz()
            }
            fn config_record(
                &mut self,
                source: $crate::__deps::foc_protocol::config::ConfigSource,
                link: $crate::__deps::foc_protocol::WatchdogConfig,
                out: &mut [u8; $crate::__deps::foc_protocol::config::MAX_RECORD],
            ) -> ::core::result::Result<usize, $crate::__deps::foc_protocol::message::ErrorCode>
            {
                self.with_link(|l| $crate::DeviceContext::config_record(l, source, link, out))
            }
            fn store(
                &mut self,
                op: $crate::__deps::foc_protocol::config::StoreOp,
                staged: &[u8],
                link: $crate::__deps::foc_protocol::WatchdogConfig,
            ) -> ::core::result::Result<
                ::core::option::Option<$crate::__deps::foc_protocol::WatchdogConfig>,
                $crate::__deps::foc_protocol::message::ErrorCode,
            > {
                self.with_link(|l| $crate::DeviceContext::store(l, op, staged, link))
            }
        }
    };
}
