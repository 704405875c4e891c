use super::*;

fn topic<T>(name: &'static str) -> Topic<T> {
    Topic::new(name, "test message")
}

#[derive(Debug, Clone, PartialEq)]
struct Marker {
    x_m: f64,
}

#[test]
fn latest_value_reader_sees_newest_and_knows_whether_it_is_new() {
    let bus = Bus::new();
    let publisher = bus.publisher(topic::<Marker>("marker")).unwrap();
    let mut subscriber = bus.subscriber(topic::<Marker>("marker")).unwrap();
    assert!(!subscriber.updated());
    assert!(subscriber.latest().is_none());

    publisher.publish(Timestamp::from_millis(10), Marker { x_m: 1.0 });
    publisher.publish(Timestamp::from_millis(20), Marker { x_m: 2.0 });
    assert!(subscriber.updated());
    let newest = subscriber.take_new().unwrap();
    assert_eq!(newest.value, Marker { x_m: 2.0 });
    assert_eq!(newest.stamp, Timestamp::from_millis(20));
    assert_eq!(newest.seq, 2);
    // Seen: not new any more, but still readable as the latest value.
    assert!(!subscriber.updated());
    assert!(subscriber.take_new().is_none());
    assert_eq!(subscriber.latest().unwrap().seq, 2);

    // A subscriber created late still gets the value already there, as new.
    let mut late = bus.subscriber(topic::<Marker>("marker")).unwrap();
    assert!(late.updated());
    assert_eq!(late.take_new().unwrap().value.x_m, 2.0);

    publisher.publish(Timestamp::from_millis(30), Marker { x_m: 3.0 });
    assert_eq!(subscriber.peek().unwrap().seq, 3);
    assert!(subscriber.updated(), "peek does not mark the message seen");
}

#[test]
fn a_publisher_learns_whether_the_message_it_replaces_was_read() {
    let bus = Bus::new();
    let publisher = bus.publisher(topic::<Marker>("frame")).unwrap();
    let mut reader = bus.subscriber(topic::<Marker>("frame")).unwrap();
    let other = bus.subscriber(topic::<Marker>("frame")).unwrap();
    let at = Timestamp::from_millis;
    assert_eq!(publisher.current_read(), None);
    assert_eq!(
        publisher.publish_noting_read(at(1), Marker { x_m: 1.0 }),
        (1, None)
    );
    assert_eq!(publisher.current_read(), Some(false));
    // Asking whether it is new reads nothing.
    assert!(reader.updated());
    assert_eq!(
        publisher.publish_noting_read(at(2), Marker { x_m: 2.0 }),
        (2, Some(false))
    );
    assert_eq!(reader.take_new().unwrap().seq, 2);
    assert_eq!(publisher.current_read(), Some(true));
    assert_eq!(
        publisher.publish_noting_read(at(3), Marker { x_m: 3.0 }),
        (3, Some(true))
    );
    // Any one subscriber's read counts, peeked or taken; a take with nothing new reads nothing.
    assert!(other.peek().is_some());
    assert_eq!(
        publisher.publish_noting_read(at(4), Marker { x_m: 4.0 }).1,
        Some(true)
    );
    assert_eq!(reader.latest().unwrap().seq, 4);
    assert_eq!(
        publisher.publish_noting_read(at(5), Marker { x_m: 5.0 }).1,
        Some(true)
    );
    assert_eq!(reader.take_new().unwrap().seq, 5);
    assert!(reader.take_new().is_none());
    assert_eq!(
        publisher.publish_noting_read(at(6), Marker { x_m: 6.0 }).1,
        Some(true)
    );
    assert_eq!(
        publisher.publish_noting_read(at(7), Marker { x_m: 7.0 }).1,
        Some(false)
    );
}

#[test]
fn a_tap_sees_every_message_in_order_where_a_reader_sees_the_latest() {
    let bus = Bus::new();
    let publisher = bus.publisher(topic::<Marker>("marker")).unwrap();
    publisher.publish(Timestamp::from_millis(1), Marker { x_m: 0.0 });
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    let tap: Tap<Marker> = Box::new(move |m: &Arc<Message<Marker>>| {
        lock(&log).push((m.seq, m.value.x_m));
    });
    bus.tap(topic::<Marker>("marker"), tap).unwrap();
    let mut reader = bus.subscriber(topic::<Marker>("marker")).unwrap();
    for i in 1..=3 {
        publisher.publish(Timestamp::from_millis(10 * i), Marker { x_m: i as f64 });
    }
    // The reader had the newest; the tap every message since it was set, none before.
    assert_eq!(reader.take_new().unwrap().seq, 4);
    assert_eq!(*lock(&seen), [(2, 1.0), (3, 2.0), (4, 3.0)]);
    // One tap per topic; another type is the usual mismatch.
    let second: Tap<Marker> = Box::new(|_| {});
    assert_eq!(
        bus.tap(topic::<Marker>("marker"), second),
        Err(BusError::AlreadyTapped {
            topic: "marker".into()
        })
    );
    let other: Tap<f64> = Box::new(|_| {});
    assert!(matches!(
        bus.tap(topic::<f64>("marker"), other),
        Err(BusError::TypeMismatch { .. })
    ));
}

#[test]
fn wrong_type_or_kind_is_a_named_error() {
    let bus = Bus::new();
    let _publisher = bus.publisher(topic::<Marker>("marker")).unwrap();
    match bus.subscriber(topic::<f64>("marker")) {
        Err(BusError::TypeMismatch {
            topic,
            existing,
            requested,
        }) => {
            assert_eq!(topic, "marker");
            assert!(existing.ends_with("Marker"), "{existing}");
            assert_eq!(requested, "f64");
        }
        other => panic!("expected a type mismatch, got {other:?}"),
    }
    assert_eq!(
        bus.queue_sender(topic::<Marker>("marker"), QueueSpec::reject(4))
            .unwrap_err(),
        BusError::KindMismatch {
            topic: "marker".into(),
            existing: TopicKind::Latest,
            requested: TopicKind::Queue,
        }
    );
    assert_eq!(
        bus.publisher(topic::<Marker>("")).unwrap_err(),
        BusError::EmptyTopicName
    );
    let message = bus
        .subscriber(topic::<u8>("marker"))
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("`marker`") && message.contains("u8"),
        "{message}"
    );
}

#[test]
fn drop_oldest_queue_keeps_the_newest_and_counts_the_dropped() {
    let bus = Bus::new();
    let sender = bus
        .queue_sender(topic::<u32>("setpoints"), QueueSpec::drop_oldest(3))
        .unwrap();
    let mut receiver = bus
        .queue_receiver(topic::<u32>("setpoints"), QueueSpec::drop_oldest(3))
        .unwrap();
    for value in 1..=5 {
        let sent = sender.send(Timestamp::from_millis(value.into()), value);
        let expected = if value <= 3 {
            Sent::Queued
        } else {
            Sent::DroppedOldest
        };
        assert_eq!(sent, Ok(expected));
    }
    assert_eq!(receiver.dropped(), 2);
    assert_eq!(receiver.len(), 3);
    let values: Vec<(u64, u32)> = receiver
        .drain()
        .into_iter()
        .map(|message| (message.seq, message.value))
        .collect();
    assert_eq!(values, vec![(3, 3), (4, 4), (5, 5)]);
    assert!(receiver.recv().is_none());
    let info = &bus.topics()[0];
    assert_eq!(
        (info.published, info.dropped, info.rejected, info.depth),
        (5, 2, 0, 0)
    );
}

#[test]
fn reject_queue_hands_the_message_back_and_counts_it() {
    let bus = Bus::new();
    let sender = bus
        .queue_sender(topic::<&'static str>("events"), QueueSpec::reject(2))
        .unwrap();
    let mut receiver = bus
        .queue_receiver(topic::<&'static str>("events"), QueueSpec::reject(2))
        .unwrap();
    assert_eq!(sender.send(Timestamp::ZERO, "a"), Ok(Sent::Queued));
    assert_eq!(sender.send(Timestamp::ZERO, "b"), Ok(Sent::Queued));
    assert_eq!(sender.send(Timestamp::ZERO, "c"), Err(QueueFull("c")));
    assert_eq!(sender.rejected(), 1);
    assert_eq!(receiver.recv().unwrap().value, "a");
    assert_eq!(sender.send(Timestamp::ZERO, "d"), Ok(Sent::Queued));
    let rest: Vec<_> = receiver.drain().into_iter().map(|m| m.value).collect();
    assert_eq!(rest, vec!["b", "d"]);
    assert_eq!(receiver.dropped(), 0);
}

#[test]
fn a_queue_has_one_receiver_and_one_spec() {
    let bus = Bus::new();
    let spec = QueueSpec::reject(4);
    let sender = bus.queue_sender(topic::<u8>("q"), spec).unwrap();
    let receiver = bus.queue_receiver(topic::<u8>("q"), spec).unwrap();
    assert_eq!(
        bus.queue_receiver(topic::<u8>("q"), spec).unwrap_err(),
        BusError::ReceiverTaken { topic: "q".into() }
    );
    assert!(matches!(
        bus.queue_sender(topic::<u8>("q"), QueueSpec::drop_oldest(4)),
        Err(BusError::QueueSpecMismatch { .. })
    ));
    assert_eq!(
        bus.queue_sender(topic::<u8>("z"), QueueSpec::reject(0))
            .unwrap_err(),
        BusError::ZeroCapacity { topic: "z".into() }
    );
    // A restarted task takes the queue over with what was sent meanwhile.
    sender.send(Timestamp::ZERO, 7).unwrap();
    drop(receiver);
    let mut again = bus.queue_receiver(topic::<u8>("q"), spec).unwrap();
    assert_eq!(again.recv().unwrap().value, 7);
}

#[test]
fn publishers_on_other_threads_reach_subscribers() {
    let bus = Bus::new();
    let mut subscriber = bus.subscriber(topic::<u64>("count")).unwrap();
    let handles: Vec<_> = (0..4)
        .map(|_| {
            let publisher = bus.publisher(topic::<u64>("count")).unwrap();
            std::thread::spawn(move || {
                for i in 0..100 {
                    publisher.publish(Timestamp::ZERO, i);
                }
            })
        })
        .collect();
    for handle in handles {
        handle.join().unwrap();
    }
    assert_eq!(subscriber.latest().unwrap().seq, 400);
}
