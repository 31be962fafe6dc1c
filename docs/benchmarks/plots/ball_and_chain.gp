# physbench --sweep, scene ball_and_chain: run from this directory: gnuplot ball_and_chain.gp
# ms per step against the error, log scales; lines join each config's front, whose
# points carry their budget (substeps x iterations, or a peer's iterations).
set logscale xy
set grid
set format x '%g'
set format y '%g'
set xlabel 'ms per step (median)'
set ylabel "joint_error_max (m)"
set title "ball_and_chain"
set key outside right top title 'line: front'
if (strstrt(GPVAL_TERMINALS, 'pngcairo') > 0) {
  set terminal pngcairo size 1000,650 noenhanced font ',10'
} else {
  set terminal png size 1000,650 noenhanced
}
set output "ball_and_chain.png"
plot "ball_and_chain.dat" index 0 using 1:2 with points lc rgb "#1f77b4" pt 7 ps 1.3 notitle, \
     '' index 1 using 1:2 with linespoints lc rgb "#1f77b4" dt 1 lw 1.5 pt 7 ps 1.3 title "soft_step", \
     '' index 1 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#1f77b4" notitle, \
     "ball_and_chain.dat" index 2 using 1:2 with points lc rgb "#2ca02c" pt 5 ps 1.3 notitle, \
     '' index 3 using 1:2 with linespoints lc rgb "#2ca02c" dt 1 lw 1.5 pt 5 ps 1.3 title "pgs", \
     '' index 3 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#2ca02c" notitle, \
     "ball_and_chain.dat" index 4 using 1:2 with points lc rgb "#9467bd" pt 9 ps 1.3 notitle, \
     '' index 5 using 1:2 with linespoints lc rgb "#9467bd" dt 1 lw 1.5 pt 9 ps 1.3 title "tjsoft", \
     '' index 5 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#9467bd" notitle, \
     "ball_and_chain.dat" index 6 using 1:2 with points lc rgb "#d62728" pt 6 ps 1.3 notitle, \
     '' index 7 using 1:2 with linespoints lc rgb "#d62728" dt 2 lw 1.5 pt 6 ps 1.3 title "bullet", \
     '' index 7 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#d62728" notitle, \
     "ball_and_chain.dat" index 8 using 1:2 with points lc rgb "#ff7f0e" pt 4 ps 1.3 notitle, \
     '' index 9 using 1:2 with linespoints lc rgb "#ff7f0e" dt 2 lw 1.5 pt 4 ps 1.3 title "ode", \
     '' index 9 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#ff7f0e" notitle, \
     "ball_and_chain.dat" index 10 using 1:2 with points lc rgb "#000000" pt 8 ps 1.3 notitle, \
     '' index 11 using 1:2 with linespoints lc rgb "#000000" dt 2 lw 1.5 pt 8 ps 1.3 title "mujoco", \
     '' index 11 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#000000" notitle
set terminal svg size 1000,650 noenhanced font 'sans,12'
set output "ball_and_chain.svg"
replot
unset output
