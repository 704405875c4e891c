use hazard_train::dataset::Sample;
fn main() {
    for seed in [1u64, 5, 6] {
        let (_, frame) = Sample::render((1u64 << 40) + seed).unwrap();
        let mut img = frame.image.clone();
        for l in &frame.labels {
            let b = l.bbox;
            for x in b.x_min as usize..(b.x_max as usize).min(639) {
                img.set(x, b.y_min as usize, 255);
                img.set(x, (b.y_max as usize).min(479), 255);
            }
            for y in b.y_min as usize..(b.y_max as usize).min(479) {
                img.set(b.x_min as usize, y, 255);
                img.set((b.x_max as usize).min(639), y, 255);
            }
        }
        let mut out = format!("P5\n640 480\n255\n").into_bytes();
        out.extend_from_slice(img.data());
        std::fs::write(format!("/tmp/ht/frame{seed}.pgm"), out).unwrap();
    }
}
