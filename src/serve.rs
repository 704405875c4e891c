//! `qosrt sim --serve`: the simulated world as its own process (see `sitl::serve`), printing
//! its truth as it goes and the outcome at the end.

use crate::sim::args::{SimArgs, EXIT_NOT_LANDED};
use runtime::energy::MissionModel;
use sim::realism::Realism;
use sim::world::WorldOptions;
use sitl::serve::{serve, ServeOptions, ServeVehicle, ServedTouchdown, Truth};
use std::net::SocketAddr;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

pub fn run(model: &MissionModel, args: &SimArgs) -> ExitCode {
    if !(args.max_time_s.is_finite() && args.max_time_s > 0.0) {
        eprintln!(
            "error: --max-time-s must be a positive number of seconds, found {}",
            args.max_time_s
        );
        return ExitCode::from(crate::check::EXIT_INVALID_CONFIG);
    }
    let options = ServeOptions {
        // The served world's driver is scripted and its pad still: with a real autopilot the
        // estimator's errors are its own.
        world: WorldOptions {
            realism: Realism::ideal(),
            ..args.world(args.seed)
        },
        vehicle: args.vehicle,
        mavlink_addr: SocketAddr::from(([127, 0, 0, 1], args.mavlink_port)),
        video_port: (!args.no_video).then_some(args.video_port),
        max_time_s: args.max_time_s,
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        if let Err(error) = ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst)) {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    }
    let [north_m, east_m] = options.world.meeting_point_ne_m;
    let mavlink = match options.vehicle {
        ServeVehicle::Simulated => format!("MAVLink to udp:127.0.0.1:{}", args.mavlink_port),
        ServeVehicle::Px4Sih { instance } => format!(
            "PX4 SITL instance {instance} flies (its pose from udp:127.0.0.1:{}; its MAVLink is its own)",
            sitl::px4_sih::SIH_DISPLAY_PORT + u16::from(instance)
        ),
        ServeVehicle::Px4Hil { instance } => format!(
            "the world is PX4's HIL simulator on tcp:127.0.0.1:{} (start PX4 with \
             `-i {instance} -m none_iris`; qosrt run --mavlink udpin:0.0.0.0:{})",
            sitl::hil::px4::PX4_SIMULATOR_PORT + u16::from(instance),
            14540 + u16::from(instance)
        ),
        ServeVehicle::ArduPilotJson { instance } => format!(
            "the world is ArduPilot's JSON physics on udp:127.0.0.1:{} (start ArduCopter with \
             `-I {instance} -M JSON:127.0.0.1`; qosrt run --mavlink tcpout:127.0.0.1:{})",
            sitl::hil::ardupilot_json::JSON_SERVO_PORT + 10 * u16::from(instance),
            5760 + 10 * u16::from(instance)
        ),
    };
    eprintln!(
        "qosrt sim --serve: {mavlink}{}; the tractor waits at {north_m},{east_m} \
         (qosrt run --meeting-point-ne-m {north_m},{east_m})",
        match options.video_port {
            Some(port) => format!(", camera as RTP/H.264 to udp:127.0.0.1:{port}"),
            None => String::new(),
        },
    );
    // With --json, stdout holds only the outcome; the truth goes to stderr.
    let json = args.json;
    let print_truth = |truth: &Truth, touchdown: Option<&ServedTouchdown>| {
        let line = describe(truth, touchdown);
        if json {
            eprintln!("{line}");
        } else {
            println!("{line}");
        }
    };
    let outcome = match serve(model, &options, &stop, print_truth) {
        Ok(outcome) => outcome,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    crate::output::print_result(json, &outcome, |outcome| {
        format!(
            "{}: {}; {} frames rendered, {} streamed{}\n",
            outcome.vehicle,
            outcome.end,
            outcome.frames_rendered,
            outcome.frames_sent,
            outcome
                .video_latency_ms
                .map(|[p50, p99]| format!(" (capture to wire {p50:.1} ms median, {p99:.1} ms p99)"))
                .unwrap_or_default()
        )
    });
    if outcome.landed_on_pad {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_NOT_LANDED)
    }
}

/// One line of the world's truth.
fn describe(truth: &Truth, touchdown: Option<&ServedTouchdown>) -> String {
    let [vn, ve, vd] = truth.vehicle_ned_m;
    let [pn, pe, _] = truth.pad_ned_m;
    let mut line = format!(
        "t {:6.1} s  vehicle N {vn:7.2} E {ve:7.2} alt {:5.2} m  pad N {pn:7.2} E {pe:7.2}{}  {:.2} m apart",
        truth.time_s,
        -vd,
        if truth.tractor_moving { " moving" } else { " parked" },
        (vn - pn).hypot(ve - pe),
    );
    if let Some(touchdown) = touchdown {
        line += &format!(
            "\ntouchdown at {:.1} s: {} pad, {:.3} m from its centre, {:.2} m/s down",
            touchdown.time_s,
            if touchdown.on_pad {
                "on the"
            } else {
                "off the"
            },
            touchdown.horizontal_error_m,
            touchdown.vertical_speed_m_s
        );
    }
    line
}
