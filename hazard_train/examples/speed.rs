use candle_core::{Device, Tensor};
use hazard_train::model::{HazardNet, NetConfig};
use std::time::Instant;
fn main() {
    let d = Device::Cpu;
    let net = HazardNet::new(NetConfig::standard(), 1, &d).unwrap();
    let x = Tensor::rand(0f32, 1f32, (16, 1, 192, 192), &d).unwrap();
    for _ in 0..10 {
        let t = Instant::now();
        let raw = net.raw(&x, hazard_train::model::Mode::Train).unwrap();
        let s = raw.sqr().unwrap().sum_all().unwrap();
        let f = t.elapsed();
        let t2 = Instant::now();
        let _g = s.backward().unwrap();
        println!("fwd {:?} bwd {:?}", f, t2.elapsed());
    }
}
