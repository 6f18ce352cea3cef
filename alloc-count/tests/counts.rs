//! The counters see what they claim to see (with the allocator installed).

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

#[test]
fn counts_this_thread_other_threads_and_a_named_thread() {
    let a = vlsync_alloc_count::this_thread();
    let v: Vec<u64> = Vec::with_capacity(16);
    assert!(vlsync_alloc_count::this_thread() > a);
    let b = vlsync_alloc_count::this_thread();
    let x = v.len() + 1;
    assert_eq!(vlsync_alloc_count::this_thread(), b, "{x}");

    vlsync_alloc_count::watch_thread("counted", false);
    let before_total = vlsync_alloc_count::total();
    let (mine, w0) = (
        vlsync_alloc_count::this_thread(),
        vlsync_alloc_count::watched(),
    );
    std::thread::Builder::new()
        .name("counted".into())
        .spawn(|| std::hint::black_box(vec![1u8; 100]).len())
        .unwrap()
        .join()
        .unwrap();
    vlsync_alloc_count::unwatch_thread();
    assert!(vlsync_alloc_count::watched() > w0);
    assert!(vlsync_alloc_count::total() > before_total);
    // spawning allocates here too, but the vector was the other thread's
    assert!(vlsync_alloc_count::this_thread() >= mine);
    let w1 = vlsync_alloc_count::watched();
    std::thread::spawn(|| std::hint::black_box(vec![1u8; 100]).len())
        .join()
        .unwrap();
    assert_eq!(vlsync_alloc_count::watched(), w1, "watching is off");
}
