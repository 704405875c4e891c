//! The live view: a WebSocket client speaking Foxglove's protocol connects to a recorder's
//! server, sees the channels advertised with their schemas, subscribes, and receives what the
//! mission logs, camera frames as PNGs a viewer shows whatever the file stores them as.

use algorithms::vision::image::GrayImage;
use foxglove::messages::{CompressedImage, Log};
use prost::Message as _;
use runtime::mission::MissionPlan;
use runtime::record::{FrameCodec, Recorder, RecorderOptions, RecordingHeader, RecordingSource};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;

fn header() -> RecordingHeader {
    let plan = MissionPlan::new(vec!["transit".into(), "landing".into()], vec![10.0, 10.0]);
    RecordingHeader {
        format_version: runtime::record::FORMAT_VERSION,
        qosrt_version: "test".into(),
        source: RecordingSource::Flight,
        seed: 0,
        plan,
        phase_durations_s: vec![10.0, 10.0],
        fixed_levels: Vec::new(),
        landing_target: false,
        camera: false,
        config_file: "qos.toml".into(),
        link_peer_known: false,
        frames: Default::default(),
        frame_codec: runtime::record::FrameCodec::Png,
        recording_id: String::new(),
        part: 0,
        first_part: None,
        part_starts_ns: None,
    }
}

#[test]
fn a_foxglove_client_sees_the_channels_and_receives_what_is_logged() {
    let recorder = Recorder::start(
        &RecorderOptions {
            live: Some("127.0.0.1:0".parse().unwrap()),
            codec: FrameCodec::Compact,
            ..RecorderOptions::default()
        },
        &header(),
        &[],
    )
    .unwrap();
    let port = recorder.live_port().expect("a live server");
    let mut request = format!("ws://127.0.0.1:{port}/")
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut socket, response) = tungstenite::connect(request).unwrap();
    assert_eq!(
        response.headers().get("sec-websocket-protocol").unwrap(),
        "foxglove.sdk.v1"
    );
    if let MaybeTlsStream::Plain(tcp) = socket.get_mut() {
        tcp.set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
    }
    let deadline = Instant::now() + Duration::from_secs(20);
    let read = |socket: &mut tungstenite::WebSocket<_>| match socket.read() {
        Ok(message) => Some(message),
        Err(tungstenite::Error::Io(e))
            if e.kind() == std::io::ErrorKind::WouldBlock
                || e.kind() == std::io::ErrorKind::TimedOut =>
        {
            None
        }
        Err(error) => panic!("{error}"),
    };
    // The advertised channels, by topic: (id, encoding, schema name).
    let mut advertised = std::collections::BTreeMap::new();
    while !advertised.contains_key("/qosrt/events") || !advertised.contains_key("/camera/image") {
        assert!(Instant::now() < deadline, "advertised only {advertised:?}");
        let Some(tungstenite::Message::Text(text)) = read(&mut socket) else {
            continue;
        };
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        if json["op"] == "advertise" {
            for channel in json["channels"].as_array().unwrap() {
                advertised.insert(
                    channel["topic"].as_str().unwrap().to_string(),
                    (
                        channel["id"].as_u64().unwrap(),
                        channel["encoding"].as_str().unwrap().to_string(),
                        channel["schemaName"].as_str().unwrap().to_string(),
                    ),
                );
            }
        }
    }
    let (events_id, encoding, schema) = advertised["/qosrt/events"].clone();
    assert_eq!(
        (encoding.as_str(), schema.as_str()),
        ("protobuf", "foxglove.Log")
    );
    assert_eq!(advertised["/camera/image"].2, "foxglove.CompressedImage");
    assert_eq!(advertised["/bus/landing/setpoint"].1, "json");
    let subscribe = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{ "id": 7, "channelId": events_id }],
    });
    socket
        .send(tungstenite::Message::Text(subscribe.to_string().into()))
        .unwrap();
    // Logged until the subscription takes: the first event after it comes through.
    loop {
        assert!(Instant::now() < deadline, "no message on the subscription");
        recorder.event(12.5, "phase landing started".into());
        let Some(tungstenite::Message::Binary(data)) = read(&mut socket) else {
            continue;
        };
        // MessageData: opcode 1, subscription id (u32), log time (u64 ns), payload.
        assert_eq!(data[0], 1);
        assert_eq!(u32::from_le_bytes(data[1..5].try_into().unwrap()), 7);
        assert_eq!(
            u64::from_le_bytes(data[5..13].try_into().unwrap()),
            12_500_000_000
        );
        let log = Log::decode(&data[13..]).unwrap();
        assert_eq!(log.message, "phase landing started");
        break;
    }
    // A frame, kept in the compact codec, reaches the viewer as a PNG of the same pixels.
    let subscribe = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{ "id": 8, "channelId": advertised["/camera/image"].0 }],
    });
    socket
        .send(tungstenite::Message::Text(subscribe.to_string().into()))
        .unwrap();
    let pixels: Vec<u8> = (0..64 * 48).map(|i| (i * 7 % 251) as u8).collect();
    let frame = Arc::new(GrayImage::from_vec(64, 48, pixels.clone()).unwrap());
    for index in 0.. {
        assert!(Instant::now() < deadline, "no frame on the subscription");
        recorder.frame(13.0, 12.9, index, frame.clone());
        let Some(tungstenite::Message::Binary(data)) = read(&mut socket) else {
            continue;
        };
        if u32::from_le_bytes(data[1..5].try_into().unwrap()) != 8 {
            continue;
        }
        let image = CompressedImage::decode(&data[13..]).unwrap();
        assert_eq!(image.format, "png");
        // Stamped at the frame's capture, as the file's message is.
        let stamp = image.timestamp.unwrap();
        assert_eq!((stamp.sec(), stamp.nsec()), (12, 900_000_000));
        let decoded = image::load_from_memory(&image.data).unwrap().into_luma8();
        assert_eq!(decoded.dimensions(), (64, 48));
        assert_eq!(decoded.into_raw(), pixels);
        break;
    }
    recorder.finish().unwrap();
}
