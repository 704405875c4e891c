use hazard_train::dataset::{class_index, Sample};
use hazard_train::evaluate::{OnnxDetector, Thresholds};
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let det = OnnxDetector::load(std::path::Path::new(&path), 320, 240).unwrap();
    let th = Thresholds {
        confidence: 0.05,
        nms_iou: 0.45,
        match_iou: 0.5,
    };
    // reasons per class: [found, wrong class, iou 0.3-0.5 same class, low conf (0.05-0.5) iou>=0.5, nothing]
    let mut reasons = [[0usize; 5]; 3];
    let mut edge = [[0usize; 2]; 3];
    for seed in 0..200u64 {
        let (_, frame) = Sample::render((1u64 << 40) + seed).unwrap();
        let dets = det.detect(&frame.image, &th).unwrap();
        for l in &frame.labels {
            let c = class_index(l.class);
            let best = |f: &dyn Fn(&hazard_train::evaluate::Thresholds) -> bool| f(&th);
            let _ = best;
            let same_hi = dets
                .iter()
                .filter(|d| d.class_id == c && d.confidence >= 0.5)
                .map(|d| d.bbox.iou(&l.bbox))
                .fold(0.0, f64::max);
            let any_hi = dets
                .iter()
                .filter(|d| d.confidence >= 0.5)
                .map(|d| d.bbox.iou(&l.bbox))
                .fold(0.0, f64::max);
            let same_lo = dets
                .iter()
                .filter(|d| d.class_id == c)
                .map(|d| d.bbox.iou(&l.bbox))
                .fold(0.0, f64::max);
            let r = if same_hi >= 0.5 {
                0
            } else if any_hi >= 0.5 {
                1
            } else if same_hi >= 0.3 {
                2
            } else if same_lo >= 0.5 {
                3
            } else {
                4
            };
            reasons[c][r] += 1;
            let at_edge = l.bbox.x_min <= 0.5
                || l.bbox.y_min <= 0.5
                || l.bbox.x_max >= 639.5
                || l.bbox.y_max >= 479.5;
            if r != 0 {
                edge[c][at_edge as usize] += 1;
            }
        }
    }
    println!(
        "per class [found, wrong class, iou .3-.5, low conf, nothing]; misses [inside, at edge]"
    );
    for c in 0..3 {
        println!("class {c}: {:?} {:?}", reasons[c], edge[c]);
    }
}
