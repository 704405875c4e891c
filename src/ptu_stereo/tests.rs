use super::figures::ramp;
use super::*;

#[test]
fn the_ramp_runs_from_dark_to_light() {
    let brightness = |c: RGBColor| c.0 as u32 + c.1 as u32 + c.2 as u32;
    let mut last = 0;
    for i in 0..=20 {
        let b = brightness(ramp(i as f64 / 20.0));
        assert!(b >= last, "{i}");
        last = b;
    }
    assert_eq!(ramp(-1.0), ramp(0.0));
    assert_eq!(ramp(2.0), ramp(1.0));
}
