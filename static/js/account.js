/* The Account pages (templates/accounts/): a key or secret shown once is selected for the
 * user, and its Copy button puts it on the clipboard (or leaves it selected, where the browser
 * does not allow that: Ctrl-C then copies it). */
(function () {
  'use strict';

  function copied(button) {
    button.textContent = 'Copied';
    window.setTimeout(function () { button.textContent = 'Copy'; }, 2000);
  }

  document.addEventListener('DOMContentLoaded', function () {
    var boxes = document.querySelectorAll('input.secret');
    Array.prototype.forEach.call(boxes, function (box) {
      box.addEventListener('focus', function () { box.select(); });
    });
    if (boxes.length) {
      boxes[0].focus();
    }
    Array.prototype.forEach.call(document.querySelectorAll('[data-copy]'), function (button) {
      button.addEventListener('click', function () {
        var box = document.getElementById(button.dataset.copy);
        if (!box) return;
        box.focus();
        box.select();
        if (navigator.clipboard && window.isSecureContext) {
          navigator.clipboard.writeText(box.value).then(function () { copied(button); }, function () {
            button.textContent = 'Press Ctrl-C';
          });
        } else {
          button.textContent = 'Press Ctrl-C';
        }
      });
    });
  });
})();
