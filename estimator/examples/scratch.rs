use vlsync_common::Stream;
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let fam: vlsync_sim::families::Family = a[1].parse().unwrap();
    let seed: u64 = a[2].parse().unwrap();
    let ns: f64 = a.get(3).map(|s| s.parse().unwrap()).unwrap_or(1.0);
    let run = vlsync_sim::families::try_generate_with(fam, seed, None, ns).unwrap();
    let cfg: EstimatorConfig = match a.get(4) {
        Some(p) => {
            vlsync_config::Config::load(std::path::Path::new(p))
                .unwrap()
                .estimator
        }
        None => EstimatorConfig::default(),
    };
    let mut est = Estimator::new(&cfg);
    let (mut i, mut j) = (0, 0);
    let (cam, lidar) = (&run.cam, &run.lidar);
    while i < cam.len() || j < lidar.len() {
        let take_cam = j >= lidar.len() || (i < cam.len() && cam[i].t_ns <= lidar[j].t_ns);
        if take_cam {
            let _ = est.push(Stream::Cam, cam[i]);
            i += 1;
        } else {
            let _ = est.push(Stream::Lidar, lidar[j]);
            j += 1;
        }
        while let Some(e) = est.poll() {
            let tr = run.truth.offset_at(e.t_ref_ns);
            println!("{:7.2} {:9} err={:+8.2}ms std={:6.2} meas_err={:+8.2} sc={:.3} ra={:5.2} truth={:.4} drift={:+.1}ppm", e.t_ref_ns as f64*1e-9, e.state.name(), (e.offset_s-tr)*1e3, e.offset_std_s*1e3, (e.measured_offset_s-tr)*1e3, e.peak_score, e.peak_ratio.min(99.0), tr, e.drift*1e6);
        }
    }
    println!("{:?} crb={:.2}ms", est.stats(), run.crb_std_s * 1e3);
}
