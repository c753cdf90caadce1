//! The offline metrics of LRN Table II and FITAM Table IV, for tests that
//! score a model on held-out frames (the trainer computes the same in
//! Python for its report).

/// Area under the ROC curve of `scores` for binary `labels` (ties count
/// half); `None` unless both classes occur.
pub fn roc_auc(scores: &[f32], labels: &[bool]) -> Option<f64> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    // Mann-Whitney: average rank of the positives.
    let (mut rank_sum, mut i) = (0.0f64, 0usize);
    let pos = labels.iter().filter(|&&l| l).count();
    let neg = labels.len() - pos;
    if pos == 0 || neg == 0 {
        return None;
    }
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && scores[order[j + 1]] == scores[order[i]] {
            j += 1;
        }
        let mid_rank = (i + j) as f64 / 2.0 + 1.0;
        rank_sum += mid_rank * order[i..=j].iter().filter(|&&k| labels[k]).count() as f64;
        i = j + 1;
    }
    Some((rank_sum - (pos * (pos + 1)) as f64 / 2.0) / (pos * neg) as f64)
}

/// Class-weighted one-vs-rest ROC AUC (FITAM Table IV): each class's AUC of
/// its probability, weighted by how many samples carry it. `probs` is
/// row-major `[samples, classes]`.
pub fn class_weighted_auc(probs: &[f32], classes: usize, labels: &[usize]) -> Option<f64> {
    let (mut sum, mut weight) = (0.0, 0.0);
    for c in 0..classes {
        let scores: Vec<f32> = probs.chunks_exact(classes).map(|p| p[c]).collect();
        let is_c: Vec<bool> = labels.iter().map(|&l| l == c).collect();
        if let Some(auc) = roc_auc(&scores, &is_c) {
            let n = is_c.iter().filter(|&&x| x).count() as f64;
            sum += auc * n;
            weight += n;
        }
    }
    (weight > 0.0).then(|| sum / weight)
}

/// A label image pooled to a model's output grid, as the trainer pools it:
/// per `k` x `k` block, the mean affordance (0..1) of its labelled pixels,
/// and whether any pixel was labelled.
pub fn pool_label(
    value: &[u8],
    labelled: &[bool],
    width: usize,
    height: usize,
    k: usize,
) -> (Vec<f32>, Vec<bool>) {
    let (ow, oh) = (width / k, height / k);
    let mut sum = vec![0.0f32; ow * oh];
    let mut n = vec![0u32; ow * oh];
    for y in 0..oh * k {
        for x in 0..ow * k {
            if labelled[y * width + x] {
                let o = (y / k) * ow + x / k;
                sum[o] += value[y * width + x] as f32 / 255.0;
                n[o] += 1;
            }
        }
    }
    let mean = sum
        .iter()
        .zip(&n)
        .map(|(s, &c)| if c > 0 { s / c as f32 } else { 0.0 })
        .collect();
    (mean, n.iter().map(|&c| c > 0).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auc_by_hand() {
        // Positives 0.9, 0.4; negatives 0.5, 0.1: pairs (0.9 > 0.5, 0.9 > 0.1,
        // 0.4 < 0.5, 0.4 > 0.1) -> 3 of 4.
        let auc = roc_auc(&[0.9, 0.5, 0.4, 0.1], &[true, false, true, false]).unwrap();
        assert!((auc - 0.75).abs() < 1e-12, "{auc}");
        // A tie between a positive and a negative counts half.
        assert_eq!(roc_auc(&[0.5, 0.5], &[true, false]), Some(0.5));
        assert_eq!(roc_auc(&[0.5, 0.2], &[true, true]), None);
        // Class-weighted: class 0 separates perfectly (AUC 1, 2 samples),
        // class 1 is reversed (AUC 0, 1 sample) -> 2/3; class 2 never occurs.
        let probs = [0.8, 0.1, 0.1, 0.7, 0.2, 0.1, 0.1, 0.0, 0.9];
        let auc = class_weighted_auc(&probs, 3, &[0, 0, 1]).unwrap();
        assert!((auc - 2.0 / 3.0).abs() < 1e-12, "{auc}");
    }

    #[test]
    fn pooling_averages_labelled_pixels_only() {
        // 4x2 label, k = 2 -> 2x1: left block labelled 255 and 0 (mean 0.5),
        // right block unlabelled.
        let value = [255, 0, 9, 9, 0, 0, 9, 9];
        let labelled = [true, true, false, false, false, false, false, false];
        let (v, m) = pool_label(&value, &labelled, 4, 2, 2);
        assert_eq!(v, vec![0.5, 0.0]);
        assert_eq!(m, vec![true, false]);
    }
}
